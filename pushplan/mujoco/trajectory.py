"""Gripper trajectories: the mocap knots that carry the block's upper face through a
command list, and their export for MuJoCo.

``export_plan`` writes ``.npz`` files with

``time`` (K+1,) s; ``mocap_pos`` (K+1, 3) m and ``mocap_quat`` (K+1, 4) (w, x, y, z)
of the gripper mocap body; ``upper_centre`` (K+1, 3) m and ``upper_yaw`` (K+1,) rad of
the block's upper-face centre carried by the gripper; ``gripper`` (name).  Knot 0 is
the reference pose; knot k is reached at the end of command k.  An ``.xml`` export
is an MJCF file with one ``<key>`` per knot (``mpos``/``mquat`` of every mocap
body), for ``<include file="..."/>`` in the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from fe_contact import Command

from ..errors import InputError
from ..outputs.atomic import atomic_write_bytes, atomic_write_npz
from .frames import matrix_yaw, quat_mul, quat_z, rz
from .mjmodel import mocap_index, mujoco_module
from .scene import MjcfScene


@dataclass(frozen=True)
class GripperTrajectory:
    """Gripper knots, one per command boundary (see the module docstring).

    Shapes: ``time`` (K+1,), ``mocap_pos`` (K+1, 3), ``mocap_quat`` (K+1, 4),
    ``upper_centre`` (K+1, 3), ``upper_yaw`` (K+1,)."""

    time: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    upper_centre: np.ndarray
    upper_yaw: np.ndarray
    gripper: str

    def at(self, k: int, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Mocap (pos, quat) a fraction ``s`` in [0, 1] of the way from knot k to k+1."""
        pos = (1 - s) * self.mocap_pos[k] + s * self.mocap_pos[k + 1]
        dyaw = (1 - s) * self.upper_yaw[k] + s * self.upper_yaw[k + 1] - self.upper_yaw[0]
        return pos, quat_mul(quat_z(dyaw), self.mocap_quat[0])


def gripper_trajectory(scene: MjcfScene, mj_model, commands: Sequence[Command], gripper: str = "gripper",
                       control_period: float = 0.05) -> GripperTrajectory:
    """Mocap knots that carry the block's upper face through ``commands``.

    The upper-face centre is rigidly attached to the gripper (yaw only; tilt is not
    representable by the FE command): each command moves it by ``(dx, dy, dz)``
    (FE frame, converted to world) and turns the gripper by ``dtheta``.

    Raises
    ------
    InputError
        ``gripper`` is not a mocap body, bad ``control_period`` or command.
    """
    mj = mujoco_module()
    if not (isinstance(control_period, (int, float)) and math.isfinite(control_period) and control_period > 0):
        raise InputError(f"control_period must be > 0 s, got {control_period!r}")
    mocap_index(mj_model, gripper)
    bid = mj.mj_name2id(mj_model, mj.mjtObj.mjOBJ_BODY, gripper)
    for i, c in enumerate(commands):
        if not isinstance(c, Command):
            raise InputError(f"commands[{i}] must be a fe_contact.Command, got {type(c).__name__}")
    p0 = np.array(mj_model.body_pos[bid], float)
    q0 = np.array(mj_model.body_quat[bid], float)
    R0 = np.zeros(9)
    mj.mju_quat2Mat(R0, q0)
    yaw0 = matrix_yaw(R0.reshape(3, 3))
    offset = rz(-yaw0) @ (scene.upper_centre - p0)
    steps = np.array([[c.dx, c.dy, c.dz] for c in commands], float).reshape(-1, 3)
    turns = np.array([c.dtheta for c in commands], float)
    centre = scene.upper_centre + np.vstack([np.zeros(3), np.cumsum(scene.to_world(steps), axis=0)])
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(turns)])
    pos = centre - np.einsum("kij,j->ki", np.stack([rz(a) for a in yaw]), offset)
    quat = np.stack([quat_mul(quat_z(a - yaw0), q0) for a in yaw])
    times = control_period * np.arange(len(commands) + 1)
    return GripperTrajectory(times, pos, quat, centre, yaw, gripper)


def keyframes_mjcf(m, traj: GripperTrajectory) -> str:
    """MJCF text with one ``<key>`` per knot of ``traj``: ``mpos`` / ``mquat`` of every
    mocap body of ``m``, the gripper's from ``traj``, the others at their model pose."""
    mocap_bodies = np.flatnonzero(m.body_mocapid >= 0)
    order = mocap_bodies[np.argsort(m.body_mocapid[mocap_bodies])]
    mine = mocap_index(m, traj.gripper)
    fmt = lambda a: " ".join(f"{v:.17g}" for v in a.ravel())  # noqa: E731
    lines = [f'<mujoco model="{traj.gripper}_plan">',
             "  <!-- pushplan gripper trajectory: include in the scene -->", "  <keyframe>"]
    for k in range(traj.time.size):
        mpos = np.array(m.body_pos[order], float)
        mquat = np.array(m.body_quat[order], float)
        mpos[mine], mquat[mine] = traj.mocap_pos[k], traj.mocap_quat[k]
        lines.append(f'    <key name="plan_{k:03d}" time="{traj.time[k]:.17g}" '
                     f'mpos="{fmt(mpos)}" mquat="{fmt(mquat)}"/>')
    lines += ["  </keyframe>", "</mujoco>", ""]
    return "\n".join(lines)


def export_plan(path, scene: MjcfScene, commands: Sequence[Command], gripper: str = "gripper",
                control_period: float = 0.05) -> Path:
    """Write the gripper trajectory of a plan as ``.npz`` or MJCF ``<keyframe>`` ``.xml``.

    Raises
    ------
    InputError
        Unknown suffix, or the scene source is not a file (for the mocap layout).
    """
    path = Path(path)
    if path.suffix.lower() not in (".npz", ".xml"):
        raise InputError(f"plan export must be .npz or .xml, got {path.name}")
    m = scene.mj_model("export_plan")
    traj = gripper_trajectory(scene, m, commands, gripper, control_period)
    if path.suffix.lower() == ".npz":
        return atomic_write_npz(
            path, time=traj.time, mocap_pos=traj.mocap_pos, mocap_quat=traj.mocap_quat,
            upper_centre=traj.upper_centre, upper_yaw=traj.upper_yaw, gripper=np.array(gripper),
        )
    return atomic_write_bytes(path, keyframes_mjcf(m, traj).encode())
