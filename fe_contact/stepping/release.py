"""Release of the block after the last load step: the gripper lifts, along a path.

The robot's motion is the data: the gripper rises from its loaded pose to
``height`` (m, above the reference pose), taking a horizontal retreat ``away
= (dx, dy)`` (m) along with the rise on the straight line between the two
poses: a release command of rise ``dz`` moves the gripper by

    (dx, dy, dz) = (a_x dz / (h_1 - h_0), a_y dz / (h_1 - h_0), dz),      m,

``h_0 = -d`` the loaded height (``d`` the press depth, the upper face's
cumulative vertical translation ``-t_z``) and ``h_1 = height``.  Nothing
numerical in it sets the answer.

A **frictional pad** (``Model(pad=Friction(...))``, :mod:`fe_contact.contact.bodies`)
is lifted until every pad contact is open: its normal load falls to zero,
and while it falls the pad and the floor each slip when their own friction
limit is reached (:meth:`ReleaseSchedule._pad_lift`); each step is under
step-doubling error control (:mod:`fe_contact.stepping.adaptive`).  Once the
pad is open, the rest of the path moves nothing.

A **bonded pad** (the paper's displacement control) is the exact special
case of a pad that never slips: ``steps`` increments of ``d / steps`` summing
to the press depth, then further increments of ``d / steps`` while the
block still touches the floor (normal force above ``LIFT_TOL`` times the
loaded one): the block hangs from the plate, its contacts open and its
elastic lag springs back.  A block with weight is then put down again to the
height where the plate carries nothing: the plate's vertical force ``F(h) =
W - N(h)`` (N, ``N`` the floor's normal force at plate height ``h``) is
brought to zero by regula falsi (bisection when it stalls) started from the
column's own-weight compression ``h_0 = -W H / (2 E A)`` (m); the lift stops
when ``|F| <= SETTLE_FORCE / 10`` times the weight.

The earlier ``open`` release (every upper-face traction decaying to zero
through an assumed pad stiffness and grip schedule) is gone: its rest pose
depended on that stiffness and schedule (issue 28).  ``Release("open", ...)``
raises ``ValueError`` saying what to use instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fem.elasticity import internal_force
from .adaptive import controlled_step
from .release_path import pad_lift_rise, put_down_target
from .model import Command, Model, State, StepReport

MODES = ("lift",)
OPEN_REMOVED = ("mode 'open' was removed (issue 28): its rest pose depended on an assumed pad stiffness and "
                "release schedule; let go with mode 'lift' of a frictional pad (Model(pad=Friction(...)); "
                "in a scenario [gripper] friction = mu), the physical release")
GRIP_FLOOR = 0.1
"""A frictional pad's lift: its load is stepped down geometrically to this fraction of the weight before the zero."""
LIFT_TOL = 1e-9
"""Floor normal force, relative to the loaded one, below which a lifted block hangs free of the floor."""
SETTLE_FORCE = 1e-9
"""Rest: the plate's force and every node's out-of-balance force at most this fraction of the force scale
(the weight; the loaded normal force for a block without weight)."""
SETTLE_MOTION = 1e-9
"""Rest: one more step moves no node by more than this fraction of the block's largest dimension."""


@dataclass(frozen=True)
class Release:
    """How the gripper lets go after the last load step.

    Parameters
    ----------
    mode : {"lift"}
        The one release: the gripper rises (see the module docstring).
    steps : int
        Increments of the release (>= 1).
    max_steps : int
        Limit on the release's steps in all (ramp, extra lift, put-down).
    height : float
        Height above its reference pose the gripper rises to (m, >= 0): the
        robot's motion, which changes nothing once the pad is open; a bonded
        pad with weight ends where it carries nothing (it cannot rise without
        lifting the block).
    away : (float, float)
        Horizontal retreat ``(dx, dy)`` of the gripper, m, taken along with the
        rise on the straight line from the loaded pose to ``height`` (module
        docstring): a loaded frictional pad drags the block with it.
    error_tol : float
        A frictional pad's lift: the error of the rest pose the adaptive steps
        allow, as a fraction of the loaded lag (of the block's size without a
        lag), in (0, 1): each step of ``steps`` is checked by step doubling and
        refined where it needs it (:func:`fe_contact.stepping.adaptive.controlled_step`).
    """

    mode: str
    steps: int
    max_steps: int = 200
    height: float = 0.0
    away: tuple = (0.0, 0.0)
    error_tol: float = 1e-2

    def __post_init__(self):
        if self.mode == "open":
            raise ValueError(OPEN_REMOVED)
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("steps", "max_steps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if not 0 < self.error_tol < 1:
            raise ValueError(f"error_tol must be in (0, 1), got {self.error_tol}")
        if not (np.isfinite(self.height) and self.height >= 0):
            raise ValueError(f"height must be >= 0 m, got {self.height}")
        away = np.asarray(self.away, dtype=float) if np.ndim(self.away) == 1 else np.full(3, np.nan)
        if away.shape != (2,) or not np.all(np.isfinite(away)):
            raise ValueError(f"away must be a finite (dx, dy) in m, got {self.away!r}")
        object.__setattr__(self, "away", (float(away[0]), float(away[1])))


class ReleaseSchedule:
    """The commands of a release, each chosen after the previous step's report.

    ``next_command(state, report)`` returns the next :class:`Command`, or None
    when the block is released (or ``max_steps`` were taken); ``report`` is
    the last step's (None before the first release step).
    """

    def __init__(self, model: Model, release: Release, state: State, loaded: StepReport | None = None):
        self.release = release
        self.weight = model.weight
        self.depth = max(0.0, -float(state.upper_translation[2]))
        self.pad = model.pad is not None
        if self.pad and model.material.density <= 0:
            raise ValueError("a frictional pad lets go of a block with weight only (material density > 0): "
                             "without weight nothing holds the block once the pad's load is zero")
        if self.pad and loaded is None:
            raise ValueError("a frictional pad's release needs the loaded step's report (loaded=...)")
        if self.depth == 0:
            raise ValueError("a lift release needs a press before it (the upper face's height must be below "
                             f"its reference one, got {float(state.upper_translation[2])} m)")
        self.loaded_normal = abs(loaded.normal_force) if loaded is not None else 0.0
        # the path: retreat (m) per m of rise, from the loaded height to Release.height
        self.retreat = np.array(release.away) / (release.height + self.depth)
        lx, ly, lz = model.mesh.size
        self.size = max(lx, ly, lz)
        self.risen = False
        self.axial_stiffness = model.material.young * lx * ly / lz  # E A / H, N/m
        self.lifted_off = False
        self.contact_points: list[tuple[float, float, bool]] = []  # (plate height m, force N, touching) putting down
        self.loaded_pad = -float(loaded.upper_force[2]) if loaded is not None else 0.0
        lag = float(np.linalg.norm(loaded.lag)) if loaded is not None else 0.0
        self.error_tol = release.error_tol * (lag if lag > 0 else self.size)  # m
        if self.pad:
            self.pad_points: list[tuple[float, float]] = []  # (pad height m, pad load N) lifting
        self.taken = 0
        self.height_partials: dict = {}  # the last command's height: its partial derivatives (put_down_target)

    @property
    def force_scale(self) -> float:
        """Force scale of the rest criteria, N: the weight, or the loaded normal force without weight."""
        return self.weight if self.weight > 0 else self.loaded_normal

    def next_command(self, state: State, report: StepReport | None) -> Command | None:
        rel, j = self.release, self.taken
        if j >= rel.max_steps or (report is not None and not report.converged):
            return None
        command = self._lift(j, state, report)
        self.taken += command is not None
        return command

    def take(self, model: Model, state: State, command: Command, step, consume: bool = False):
        """``command`` from ``state`` with ``step`` (``step(model, state,
        command, consume=...)``): a frictional pad's lift under step-doubling
        error control (``Release.error_tol`` of the lag over the press depth,
        :func:`~fe_contact.stepping.adaptive.controlled_step`, which keeps
        ``state``), any other release step as it is.  Returns (State, StepReport)."""
        if self.pad and command.moves:
            return controlled_step(model, state, command, step, self.error_tol, self.depth)
        return step(model, state, command, consume=consume)

    def _along(self, dz: float) -> Command:
        """The gripper's motion of rise ``dz`` (m) along the release's path (module docstring)."""
        return Command(dx=float(self.retreat[0] * dz), dy=float(self.retreat[1] * dz), dz=dz)

    def _lift(self, j: int, state: State, report: StepReport | None) -> Command | None:
        if self.pad:
            return self._pad_lift(j, state, report)
        dz = self.depth / self.release.steps
        self.height_partials = {"current": 1.0, "depth": 1.0 / self.release.steps}
        if j < self.release.steps:
            return self._along(dz)
        if not self.lifted_off:
            if report.normal_force > LIFT_TOL * max(self.loaded_normal, self.weight):
                return self._along(dz)
            self.lifted_off = True
        if self.weight == 0:
            return self._rise(state)  # nothing to put down: the plate carries nothing off the floor
        return self._put_down(state, report)

    def _rise(self, state: State) -> Command | None:
        """Up to ``Release.height`` once the gripper has let go, one settle step
        (the rise's predictor stretches the block: its force scale is the
        stretch's), then the end."""
        dz = self.release.height - float(state.upper_translation[2])
        if dz > SETTLE_MOTION * self.size:
            self.risen = True
            self.height_partials = {}  # an absolute height
            return self._along(dz)
        if self.risen:
            self.risen = False
            self.height_partials = {"current": 1.0}
            return Command()
        return None

    def _pad_lift(self, j: int, state: State, report: StepReport | None) -> Command | None:
        """The next rise of a frictional pad: to the pad load ``max(N - N_0 /
        steps, q N)`` (uniform steps of the loaded pad load ``N_0`` while it is
        large, geometric ones of ratio ``q`` towards zero, ``q`` taking
        ``steps`` down to ``GRIP_FLOOR`` times the weight), then past the
        zero; the height step is predicted by the secant of the pad load
        against its height.  Once every pad contact is open, one settle step
        (``Command()``) and the end."""
        h = float(state.upper_translation[2])
        pad_force = np.abs(self.loaded_pad) if report is None else np.linalg.norm(report.upper_force)
        load = self.loaded_pad if report is None else -float(report.upper_force[2])
        if pad_force <= 0.1 * SETTLE_FORCE * self.weight:
            if self.lifted_off:
                return self._rise(state)
            self.lifted_off = True
            self.height_partials = {"current": 1.0}
            return Command()
        self.pad_points.append((h, load))
        dz, partials = pad_lift_rise(self.pad_points, self.loaded_pad, self.depth, self.weight, self.release.steps,
                                     GRIP_FLOOR)
        last = ("h", len(self.pad_points) - 1)
        partials[last] = partials.get(last, 0.0) + 1.0  # the height h + dz
        self.height_partials = partials
        return self._along(dz)

    def _put_down(self, state: State, report: StepReport) -> Command | None:
        """The next step of the search for the height where the plate carries
        nothing (see the module docstring): regula falsi on the bracket of the
        lowest height where it pulls (``F > 0``; off the floor ``F = W``) and
        the highest where it pushes, bisecting when a step does not halve
        ``|F|``; below the first bracket, the own-weight compression."""
        h, force = float(state.upper_translation[2]), float(report.upper_force[2])
        if abs(force) <= 0.1 * SETTLE_FORCE * self.weight and np.linalg.norm(report.upper_force) <= \
                SETTLE_FORCE * self.weight:
            return None
        points, touching = self.contact_points, report.normal_force > LIFT_TOL * self.weight
        slow = bool(points) and points[-1][2] and touching and abs(force) > 0.5 * abs(points[-1][1])
        points.append((h, force, touching))
        target, self.height_partials = put_down_target(points, self.weight, self.axial_stiffness, slow, LIFT_TOL)
        return self._along(target - h)


@dataclass(frozen=True)
class Rest:
    """Whether a released block is at rest, and the measures that say so.

    ``status`` is ``"settled"`` when the plate (or pad) carries at most
    ``SETTLE_FORCE`` times the force scale, every node not held by the plate
    is in equilibrium of the unregularised problem (internal, weight and
    contact forces, no regularising spring) to the same fraction, and one more
    step moves no node by more than ``SETTLE_MOTION`` times the block's
    largest dimension; otherwise ``"not_settled"`` and ``reason`` names the
    criteria that fail.

    Attributes
    ----------
    status : {"settled", "not_settled"}
    reason : str
    pad_force : float
        Norm of the plate's total force on the block, N.
    imbalance : float
        Largest out-of-balance force of a node, N.
    further_motion : float
        Largest nodal displacement in one more step, m (inf if that step failed).
    force_scale : float
        The weight (the loaded normal force without weight), N.
    """

    status: str
    reason: str
    pad_force: float
    imbalance: float
    further_motion: float
    force_scale: float

    @property
    def settled(self) -> bool:
        return self.status == "settled"


def rest_check(model: Model, state: State, report: StepReport, schedule: ReleaseSchedule, step) -> Rest:
    """:class:`Rest` of ``state``, the end of a release (``report`` its last
    step's) run by ``schedule``; ``step`` is :func:`fe_contact.stepping.step.step`
    (it takes the one more step, from ``state``, which it does not modify).

    The one more step is judged by its last iterate, converged or not: a null
    step of a stress-free block in the air has no force scale but rounding,
    and its Newton loop cannot meet a tolerance relative to that; its iterate
    is accepted when it is in equilibrium by the same absolute measure as the
    state."""
    scale = schedule.force_scale
    held = model.pad is None
    pad, imbalance = _balance(model, state.displacement, state.reaction, held, report.upper_force)
    _, further = step(model, state, Command())
    _, further_imbalance = _balance(model, further.displacement,
                                    np.vstack([further.reaction_local, further.pad_reaction]), held, further.upper_force)
    motion = float(np.abs(further.displacement - state.displacement).max())
    if not np.isfinite(motion) or further_imbalance > SETTLE_FORCE * scale:
        motion = np.inf
    failing = []
    if not report.converged:
        failing.append(f"the last release step did not converge ({report.message})")
    if np.linalg.norm(pad) > SETTLE_FORCE * scale:
        failing.append(f"the pad still carries {np.linalg.norm(pad):.3g} N (> {SETTLE_FORCE:g} x {scale:.3g} N)")
    if imbalance > SETTLE_FORCE * scale:
        failing.append(f"a node is out of balance by {imbalance:.3g} N (> {SETTLE_FORCE:g} x {scale:.3g} N)")
    if motion > SETTLE_MOTION * max(model.mesh.size):
        failing.append(f"one more step moves a node by {motion:.3g} m (> {SETTLE_MOTION:g} x block size; "
                       f"{further.message})")
    if failing and schedule.taken >= schedule.release.max_steps:
        failing.append(f"the release stopped at max_steps = {schedule.release.max_steps}")
    return Rest("not_settled" if failing else "settled", "; ".join(failing) or "settled",
                float(np.linalg.norm(pad)), imbalance, motion, scale)


def _balance(model: Model, U: np.ndarray, reaction: np.ndarray, held: bool, upper_force: np.ndarray):
    """The pad's total force on the block (3,), N, and the largest out-of-balance
    force of a node not held by it, N, of the unregularised problem at
    displacements ``U`` (n_nodes, 3) with contact forces ``reaction``
    (n_lower, 3, local): ``f_int - f_weight - f_contact`` per node (the
    plate's reactions, for a ``held`` upper face, are the pad force;
    otherwise the pad's force is the step's ``upper_force``)."""
    f_int, _ = internal_force(model.geometry, model.mesh.elements, U, model.material)
    f = f_int.reshape(-1, 3)
    if model.body_force is not None:
        f = f - model.body_force.reshape(-1, 3)
    np.subtract.at(f, model.contacts.nodes, model.contacts.to_world(reaction))
    pad = f[model.mesh.upper].sum(axis=0) if held else np.asarray(upper_force, dtype=float)
    if held:
        f[model.mesh.upper] = 0.0
    if not np.all(np.isfinite(f)):
        return pad, np.inf
    return pad, float(np.linalg.norm(f, axis=1).max())
