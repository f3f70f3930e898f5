"""Episodes of the closed loop to a rest target: after a release the block's rest pose
is observed (as a camera would); when it is outside the tolerance the gripper grasps the
block again where it lies, presses, pushes the correction and releases, up to ``[plan]
episodes`` times (:data:`~pushplan.limits.MAX_EPISODES` at most).

The re-grasp (:func:`regrasp`).  The gripper is placed over the resting block: its plate
pose is the in-plane rigid pose ``(t_x, t_y, theta)`` that best maps the reference
positions ``X`` of the pad's nodes (``Model.held_nodes``) onto their rest positions
``x`` (least squares)

    theta = the 2D Kabsch rotation of X onto x (:func:`fe_contact.planar_yaw`),
    t = x_bar - c - R(theta) (X_bar - c),   c the face's reference centre,

and its height puts the pad on the block: a frictional pad touches the highest pad
node (gap 0, no force: moving the pad through the air is no physics), a bonded pad
bonds at the nodes' mean height, and one FE step with a zero command puts the held
nodes on that rigid pose (the plate is flat; the resting face is flat to its residual
strain).  Then the scenario's press is applied, as in the first episode.

Each episode is planned from the observed rest pose: the planner's block starts at its
reference, so an episode's poses and target are relative to where the block rests
(world axes: the floor's friction axes do not turn with the block; the block's own turn
since the first grasp is taken as small).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Command, Model, State, planar_yaw

from ..config.plan import PlanSpec


def plate_over(model: Model, state: State) -> tuple[np.ndarray, float]:
    """The gripper's pose over the block at ``state``: translation (3,), m, and
    rotation about z, rad, in the conventions of ``State.upper_translation`` /
    ``upper_rotation`` (module docstring)."""
    nodes = model.held_nodes
    X = model.mesh.nodes[nodes]
    x = X + state.displacement[nodes]
    theta = planar_yaw(X, x, np.ones(nodes.size))
    c, s = math.cos(theta), math.sin(theta)
    centre = model.upper_centre[:2]
    rel = X[:, :2].mean(axis=0) - centre
    t_xy = x[:, :2].mean(axis=0) - centre - np.array([c * rel[0] - s * rel[1], s * rel[0] + c * rel[1]])
    rise = x[:, 2] - X[:, 2]
    t_z = float(rise.max()) if model.pad is not None else float(rise.mean())
    return np.array([t_xy[0], t_xy[1], t_z]), theta


def regrasp(model: Model, state: State) -> tuple[State, tuple[Command, ...]]:
    """The state with the gripper placed over the resting block (:func:`plate_over`),
    and the commands that grasp it before the press: none for a frictional pad, one
    zero command for a bonded one (the step that bonds the face to the plate)."""
    translation, theta = plate_over(model, state)
    placed = dataclasses.replace(state, upper_translation=translation, upper_rotation=theta,
                                 plate=np.array([translation[0], translation[1], theta]), tangent=None)
    return placed, (() if model.pad is not None else (Command(),))


def relative_summary(summary, origin: np.ndarray):
    """A step summary with its poses relative to ``origin`` ``(x, y, yaw)`` (m, rad)."""
    shift = np.array([origin[0], origin[1], 0.0])
    return dataclasses.replace(summary, lower_centroid=tuple(np.asarray(summary.lower_centroid) - shift),
                               upper_centroid=tuple(np.asarray(summary.upper_centroid) - shift),
                               lower_yaw=summary.lower_yaw - float(origin[2]))


def episode_spec(spec: PlanSpec, origin: np.ndarray, gain: np.ndarray) -> PlanSpec:
    """``spec`` for an episode from the rest pose ``origin`` (world, m, m, rad): the
    rest displacement left to the target, divided by the truth's response ``gain``
    (:func:`response_gain`, (3,)), as the episode's target relative to ``origin``."""
    mask = np.array([1.0, 1.0, float(spec.yaw_targeted)])
    target = (np.array(spec.target) - origin) / np.asarray(gain, float) * mask
    return dataclasses.replace(spec, target=tuple(float(v) for v in target))


GAIN_BOUNDS = (0.1, 10.0)
"""The response gain of :func:`response_gain` is clipped to these: an episode aims at most
10x further than what is left (and at least a tenth of it), whatever one episode measured."""
NO_AIM = 1e-12
"""An aimed displacement (m, or rad) below which an episode says nothing about the gain."""


def response_gain(observed: np.ndarray | None, aimed: np.ndarray | None) -> np.ndarray:
    """The truth's rest response to what the last episode aimed at (3,): the secant gain

        g_xy = (r . a) / (a . a)   over (x, y),    g_yaw = r_yaw / a_yaw,

    ``r`` the rest displacement the truth made over that episode, ``a`` the one its plan
    aimed at (each (3,), m, m, rad), clipped to :data:`GAIN_BOUNDS`; ones before any
    episode (or where nothing was aimed).  The next episode aims at ``left / g``: a truth
    that moves 0.4x what the model predicts is asked for 2.5x (a gain, not an additive
    offset carried from one re-grasp to the next, which overshoots once the block is
    close: the offset does not shrink with what is left)."""
    g = np.ones(3)
    if observed is None:
        return g
    r, a = np.asarray(observed, float), np.asarray(aimed, float)
    aa = float(a[0] ** 2 + a[1] ** 2)
    if aa > NO_AIM**2:
        g[:2] = float(r[0] * a[0] + r[1] * a[1]) / aa
    if abs(a[2]) > NO_AIM:
        g[2] = r[2] / a[2]
    return np.clip(g, *GAIN_BOUNDS)


@dataclass(frozen=True)
class Episode:
    """One grasp, push and release cycle of the closed loop (world poses, m, rad).

    ``origin`` is the observed rest pose it started from (zeros for the first: the
    block's reference), ``aimed`` the rest displacement its plan aimed at, relative to
    ``origin``, ``loaded`` the pose observed after its last push, ``rest`` the rest
    pose observed after its release, ``error`` the rest pose's against the target."""

    index: int
    origin: np.ndarray
    aimed: np.ndarray
    iterations: tuple
    loaded: np.ndarray
    rest: np.ndarray
    error: dict
    regrasp_steps: int
    wall_time: float

    def to_dict(self) -> dict:
        return {"episode": self.index, "origin_pose": pose_json(self.origin), "aimed_rest": pose_json(self.aimed),
                "regrasp_steps": self.regrasp_steps, "loaded_pose": pose_json(self.loaded),
                "rest_pose": pose_json(self.rest), "rest_error": self.error,
                "iterations": [it.to_dict() for it in self.iterations], "wall_time_s": self.wall_time}


def pose_json(pose) -> list[float]:
    """``(x, y, yaw)`` (m, rad) as written in files: ``[x, y, yaw_deg]``
    (:data:`pushplan.planning.document.POSE_UNITS`)."""
    return [float(pose[0]), float(pose[1]), math.degrees(float(pose[2]))]
