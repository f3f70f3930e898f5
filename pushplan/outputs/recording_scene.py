"""What a recording draws besides the block (world coordinates, m, z up): the floor,
the friction ellipse of the surface, the gripper plate and the plan overlays.

``world/floor``     Boxes3D (static): the plane z = 0, three block footprints wide.
``world/friction``  LineStrips3D + Arrows3D (static): the friction ellipse
                    ``(mu_x cos t, mu_y sin t)`` in the orthotropy frame (axis ``t_x`` at
                    ``angle_deg`` from x), drawn on the floor around the block, its larger
                    semi-axis 0.75 of the block's half-width; the arrows are ``t_x`` and
                    ``t_y`` scaled by ``mu_x`` and ``mu_y``.
``world/gripper``   Boxes3D per step: the upper-face plate at the upper face's pose.
``plan/*``          see :meth:`pushplan.outputs.recording.Recorder.log_plan`.
"""

from __future__ import annotations

import math

import numpy as np

from fe_contact import local_frame

FLOOR_COLOUR = (200, 200, 200, 90)
FRICTION_COLOUR = (250, 150, 30)
GRIPPER_COLOUR = (90, 90, 110, 120)
GRIPPER_THICKNESS = 0.05  # of the block height
PLAN_COLOURS = {"predicted": (80, 140, 255), "verified": (40, 200, 80), "naive": (230, 60, 60)}
ELLIPSE_POINTS = 97


def floor(rr, size) -> object:
    lx, ly, _ = size
    return rr.Boxes3D(centers=[[0.0, 0.0, 0.0]], half_sizes=[[1.5 * lx, 1.5 * ly, 0.0]], colors=[FLOOR_COLOUR],
                      fill_mode=rr.components.FillMode.Solid, labels=["floor z = 0"])


def friction_ellipse(rr, size, friction: dict) -> list:
    """Archetypes of the friction ellipse of a scenario's ``friction`` table."""
    mu_x, mu_y = float(friction["mu_x"]), float(friction["mu_y"])
    angle = math.radians(float(friction.get("angle_deg", 0.0)))
    scale = 0.75 * 0.5 * min(size[0], size[1]) / max(mu_x, mu_y, 1e-12)
    t = np.linspace(0.0, 2.0 * np.pi, ELLIPSE_POINTS)
    T = local_frame(angle)  # rows n, t_x, t_y in world coordinates
    local = np.column_stack([np.zeros(len(t)), mu_x * np.cos(t), mu_y * np.sin(t)]) * scale
    world = local @ T + [0.0, 0.0, 1e-6 * size[2]]
    axes = scale * np.array([mu_x, mu_y])[:, None] * T[1:]
    return [rr.LineStrips3D([world], colors=[FRICTION_COLOUR],
                            labels=[f"friction ellipse mu_x = {mu_x:g}, mu_y = {mu_y:g}"]),
            rr.Arrows3D(origins=np.zeros((2, 3)), vectors=axes, colors=[FRICTION_COLOUR],
                        labels=[f"t_x (mu_x = {mu_x:g})", f"t_y (mu_y = {mu_y:g})"])]


def gripper(rr, size, upper_centre, yaw: float) -> object:
    """The gripper plate on the upper face: ``upper_centre`` (3,) m, ``yaw`` rad."""
    lx, ly, lz = size
    thickness = GRIPPER_THICKNESS * lz
    centre = np.asarray(upper_centre, float) + [0.0, 0.0, thickness / 2]
    return rr.Boxes3D(centers=[centre], half_sizes=[[lx / 2, ly / 2, thickness / 2]],
                      rotation_axis_angles=[rr.RotationAxisAngle(axis=[0, 0, 1], radians=yaw)],
                      colors=[GRIPPER_COLOUR], fill_mode=rr.components.FillMode.Solid, labels=["gripper"])


def target_box(rr, size, target) -> object:
    yaw = float(target[2]) if len(target) == 3 else 0.0
    return rr.Boxes3D(centers=[[target[0], target[1], 0.0]], half_sizes=[[size[0] / 2, size[1] / 2, 0.0]],
                      rotation_axis_angles=[rr.RotationAxisAngle(axis=[0, 0, 1], radians=yaw)],
                      colors=[(255, 200, 0)], labels=["target"])


def pose_path(rr, name: str, poses: np.ndarray, arrow: float) -> list:
    """A plan's lower-face poses (n, 2|3) as a line strip with points and yaw arrows."""
    xyz = np.column_stack([poses[:, :2], np.zeros(len(poses))])
    colour = PLAN_COLOURS[name]
    archetypes = [rr.LineStrips3D([xyz], colors=[colour], labels=[name]), rr.Points3D(xyz, colors=[colour])]
    if poses.shape[1] == 3:
        heading = arrow * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2]), np.zeros(len(poses))])
        archetypes.append(rr.Arrows3D(origins=xyz, vectors=heading, colors=[colour]))
    return archetypes
