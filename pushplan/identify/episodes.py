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

The episodes stop short of their cap, a failure, when one after the first removes less
than :data:`MIN_PROGRESS` of the error it started from (:func:`progress_stop`), or when the
response gain an episode measured (:func:`gain_stop`), or the rest displacement of one that
went as far as its steps allow (:func:`reach_stop`), says the next cannot: the number of
episodes is then logarithmic in the first one's error over the tolerance (:data:`MIN_PROGRESS`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Command, Model, State, planar_yaw

from ..config.plan import PlanSpec
from ..planning.target import pose_error


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


def secant_gain(observed: np.ndarray, aimed: np.ndarray) -> np.ndarray:
    """The truth's rest response to what an episode aimed at (3,), unclipped: the secant gain

        g_xy = (r . a) / (a . a)   over (x, y),    g_yaw = r_yaw / a_yaw,

    ``r`` the rest displacement the truth made over that episode, ``a`` the one its plan
    aimed at (each (3,), m, m, rad); NaN where nothing was aimed (below :data:`NO_AIM`)."""
    r, a = np.asarray(observed, float), np.asarray(aimed, float)
    g = np.full(3, np.nan)
    aa = float(a[0] ** 2 + a[1] ** 2)
    if aa > NO_AIM**2:
        g[:2] = float(r[0] * a[0] + r[1] * a[1]) / aa
    if abs(a[2]) > NO_AIM:
        g[2] = r[2] / a[2]
    return g


def response_gain(observed: np.ndarray | None, aimed: np.ndarray | None) -> np.ndarray:
    """The gain (3,) the next episode divides what is left by: :func:`secant_gain` clipped
    to :data:`GAIN_BOUNDS`; ones before any episode (or where nothing was aimed).  The next
    episode aims at ``left / g``: a truth that moves 0.4x what the model predicts is asked
    for 2.5x (a gain, not an additive offset carried from one re-grasp to the next, which
    overshoots once the block is close: the offset does not shrink with what is left)."""
    if observed is None:
        return np.ones(3)
    g = secant_gain(observed, aimed)
    return np.clip(np.where(np.isnan(g), 1.0, g), *GAIN_BOUNDS)


MIN_PROGRESS = 0.5
"""The fraction of the rest error (in units of the tolerances, :func:`tolerance_units`) an
episode aimed over a measured gain must remove, else the loop stops (:func:`progress_stop`).
Where the rest responds in proportion to the aim such an episode removes all that is left,
so removing less than half means the truth's response differs from the measured gain by
more than half of it (or the pushes an episode may make reach less than half of what is
left): another episode would do no better.  The same fraction bounds what the next episode
is predicted to remove from the gain (:func:`gain_stop`) or from the reach
(:func:`reach_stop`) of the one before.  So every episode the loop goes on from, but the
first and the one that first measures a gain, cut the error to 1/2 (aimed over a measured
gain) or 2/3 (at its reach: it moved the block at least half of what is left after it) of
what it started from: the episodes are logarithmic in the first one's error over the
tolerance, ``[plan] episodes`` at most."""


def tolerance_units(pose, spec: PlanSpec) -> float:
    """A rest pose's error in units of the tolerances: ``max(e / tol, |e_yaw| / yaw_tol)``
    (the yaw's with a yaw target); within tolerance where <= 1."""
    pos, yaw = pose_error(pose, spec)
    return max(pos / spec.tolerance, yaw / spec.yaw_tolerance)


@dataclass(frozen=True)
class Stop:
    """Why the episodes stopped before the tolerance or their cap: ``rule`` ``"progress"``
    (episode ``episode`` removed ``removed``, a fraction, of the error it started from:
    less than :data:`MIN_PROGRESS`), ``"gain"`` (the response ``gain`` episode ``episode``
    measured says the next, aiming at most ``1 / GAIN_BOUNDS[0]`` times what is left, would
    remove ``predicted`` of it, less than :data:`MIN_PROGRESS`) or ``"reach"`` (episode
    ``episode`` went as far as its steps allow and moved the block ``predicted`` of what is
    left after it: the next, at most as far, would remove that much); ``message`` in words."""

    rule: str
    episode: int
    message: str
    removed: float | None = None
    gain: float | None = None
    predicted: float | None = None

    def to_dict(self) -> dict:
        return {"rule": self.rule, "episode": self.episode, "removed_fraction": self.removed,
                "response_gain": self.gain, "predicted_fraction": self.predicted, "min_progress": MIN_PROGRESS}


def progress_stop(before, after, index: int, spec: PlanSpec) -> Stop | None:
    """A :class:`Stop` when episode ``index``, from the rest pose ``before`` to ``after``
    (m, m, rad), ends outside the tolerance having removed less than :data:`MIN_PROGRESS`
    of the error (:func:`tolerance_units`) it started from; None otherwise."""
    start, end = tolerance_units(before, spec), tolerance_units(after, spec)
    removed = 1.0 - end / start
    if end <= 1.0 or removed >= MIN_PROGRESS:
        return None
    what = "farther than it started" if removed < 0 else f"it removed {removed:.1%} of its error"
    return Stop("progress", index, f"episode {index} ended {end:.3g} tolerances off from {start:.3g}: {what}, less "
                f"than the {MIN_PROGRESS:.0%} an episode must remove: the loop stops (the truth does not respond "
                "as its measured gain predicts, or an episode's pushes reach too little of what is left)",
                removed=removed)


def gain_stop(gain, rest, index: int, spec: PlanSpec) -> Stop | None:
    """A :class:`Stop` when the raw response ``gain`` (:func:`secant_gain`, (3,)) episode
    ``index`` measured is below ``MIN_PROGRESS * GAIN_BOUNDS[0]`` in a component still
    outside its tolerance at ``rest``: the next episode, aiming at most ``1 / GAIN_BOUNDS[0]``
    times what is left, would move the block less than :data:`MIN_PROGRESS` of it."""
    pos, yaw = pose_error(rest, spec)
    outside = [pos > spec.tolerance, False, yaw > spec.yaw_tolerance]
    weak = [j for j in (0, 2) if outside[j] and not np.isnan(gain[j]) and gain[j] < MIN_PROGRESS * GAIN_BOUNDS[0]]
    if not weak:
        return None
    g = float(gain[weak[0]])
    return Stop("gain", index, f"episode {index}'s rest moved {g:.3g}x the {'yaw' if weak[0] else 'displacement'} it "
                f"aimed at: the next, aiming at most {1 / GAIN_BOUNDS[0]:g}x what is left, would remove less than "
                f"{MIN_PROGRESS:.0%} of it: the loop stops (the pushes hardly move the block's rest pose: a pad "
                "that slides on it?)", gain=g, predicted=g / GAIN_BOUNDS[0])


def reach_stop(moved, rest, index: int, spec: PlanSpec) -> Stop | None:
    """A :class:`Stop` when episode ``index``, which went as far as its steps allow (a plan
    beyond reach), moved the block's rest ``moved`` (3,) (m, m, rad) less than
    :data:`MIN_PROGRESS` of the position error ``l`` left at ``rest``, along it:
    ``(moved . l) / (l . l)`` over (x, y).  The next episode's pushes are bounded as this
    one's were (``steps`` of ``max_step``), and this one used them to their bound: the rest
    moving with the push, the next would move the block about as far at most, less than
    half of what is left."""
    left = np.asarray(spec.target[:2]) - np.asarray(rest[:2], float)
    if pose_error(rest, spec)[0] <= spec.tolerance:
        return None
    p = float(np.dot(np.asarray(moved[:2], float), left) / np.dot(left, left))
    if p >= MIN_PROGRESS:
        return None
    return Stop("reach", index, f"episode {index} went as far as its steps allow and moved the block's rest {p:.3g} of "
                f"what is left after it: the next, no further, would remove less than {MIN_PROGRESS:.0%} of it: the "
                "loop stops (the pushes hardly move the block's rest pose: a pad that slides on it?)", predicted=p)


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
