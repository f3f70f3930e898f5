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
is unloaded by load control (issue 39): ``steps`` load steps take the pad's
normal load from its loaded value ``P_0`` to zero (:func:`pad_load_schedule`:
half the steps uniform in the load, half in its logarithm down to a
thousandth of the weight; :class:`~fe_contact.stepping.command.PadLoad`); in each the pad's
height is one more unknown of the Newton loop, closed by the load
(:mod:`fe_contact.stepping.pad_load`), and the pad and the floor each slip
when their own friction limit is reached.  At ``P = 0`` every pad contact
is open; the rest of the path (up to ``height``) moves nothing, and one settle
step ends the release.  Each load step is the implicit midpoint rule
(``Release.scheme``, :mod:`~fe_contact.stepping.midpoint`:
a backward-Euler step to the mid load, extrapolated towards the end as far as every contact
stays on its branch of the contact law, then backward Euler for the rest; second order
where no contact changes state, where backward Euler is first); its cost is ``steps`` step solves (at most
``2 steps``) and two more; its accuracy is measured in docs/release.md.

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
when ``|F| <= SETTLE_FORCE / 10`` times the weight.  If the plate
still carries an in-plane force once ``|F| <= LET_GO_FORCE`` times the weight (a pad off the face's centre: the block,
hanging from it, sags on its far side, and as it is set down its lower face
sticks to the floor while it straightens, which locks a horizontal force
between the floor and the plate; measured 0.35 W on 6 x 5 x 2), no plate
height removes it: the pad lets go (:class:`~fe_contact.stepping.command.LetGo`),
one step with the upper face free in which the block comes to equilibrium on
the floor alone.

The earlier ``open`` release (every upper-face traction decaying to zero
through an assumed pad stiffness and grip schedule) is gone: its rest pose
depended on that stiffness and schedule (issue 28).  ``Release("open", ...)``
raises ``ValueError`` saying what to use instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from ..fem.elasticity import internal_force
from .command import LetGo, PadLoad
from .step import step
from .release_path import put_down_target
from .model import Command, Model, State, StepReport

MODES = ("lift",)
SCHEMES = ("midpoint", "backward_euler")
OPEN_REMOVED = ("mode 'open' was removed (issue 28): its rest pose depended on an assumed pad stiffness and "
                "release schedule; let go with mode 'lift' of a frictional pad (Model(pad=Friction(...)); "
                "in a scenario [gripper] friction = mu), the physical release")
ERROR_TOL_REMOVED = ("error_tol was removed (issue 39): a frictional pad is unloaded by load control in `steps` "
                     "load steps (no height search to control); its accuracy is set by `steps` (docs/release.md)")
LOAD_FLOOR = 1e-3
"""A frictional pad's load steps: the logarithmic half of :func:`pad_load_schedule` reaches down to this fraction
of the weight."""
LOAD_LOG_WEIGHT = 0.5
"""The share of :func:`pad_load_schedule`'s steps uniform in the logarithm of the load."""
MAX_STEPS = 100_000
"""Largest ``Release.steps`` and ``max_steps`` accepted (each step a Newton loop: a bound on the release's work)."""
PUT_DOWN_STEPS = 168
"""The default ``Release.max_steps`` is ``2 steps`` and this many more: a bonded block's put-down (its regula falsi
on the plate's height, bisecting when it stalls) and the settle steps."""
LIFT_TOL = 1e-9
"""Floor normal force, relative to the loaded one, below which a lifted block hangs free of the floor."""
SETTLE_FORCE = 1e-9
"""Rest: the plate's force and every node's out-of-balance force at most this fraction of the force scale
(the weight; the loaded normal force for a block without weight)."""
SETTLE_MOTION = 1e-9
"""Rest: one more step moves no node by more than this fraction of the block's largest dimension."""
LET_GO_FORCE = 1e-6
"""A bonded pad that still carries an in-plane force when put down lets go (:class:`LetGo`) once its vertical
force is at most this fraction of the weight: regula falsi on the plate's height cannot bring it below the Newton
loop's resolution (measured: stalled at 1.1e-9 W with 0.32 W in the plane, 4 x 3 x 2), and letting go of the rest
moves the block by about ``LET_GO_FORCE W H / (E A)`` (measured against 1e-9: tests/test_footprint.py)."""


@dataclass(frozen=True)
class Release:
    """How the gripper lets go after the last load step.

    Parameters
    ----------
    mode : {"lift"}
        The one release: the gripper rises (see the module docstring).
    steps : int
        Increments of the release, in [1, MAX_STEPS]: a bonded pad's lift
        increments of ``d / steps``; a frictional pad's load steps
        (:func:`pad_load_schedule`), which set the rest pose's accuracy
        (``scheme``: docs/release.md) and the release's cost (``steps`` step
        solves, at most ``2 steps`` with the midpoint rule).
    max_steps : int or None
        Limit on the release's steps in all (ramp, extra lift, put-down), in
        [1, MAX_STEPS]; None (default): ``2 steps + PUT_DOWN_STEPS`` (the ramp's
        or the load steps, as many again for a bonded block's lift off, and the
        put-down; 200 at 16 steps), so that no ``steps`` accepted is cut short
        by it.
    height : float
        Height above its reference pose the gripper rises to (m, >= 0): the
        robot's motion, which changes nothing once the pad is open; a bonded
        pad with weight ends where it carries nothing (it cannot rise without
        lifting the block).
    away : (float, float)
        Horizontal retreat ``(dx, dy)`` of the gripper, m, taken along with the
        rise on the straight line from the loaded pose to ``height`` (module
        docstring): a loaded frictional pad drags the block with it.
    error_tol : None
        Removed (issue 39): given, it raises ``ValueError`` saying so (the
        load-controlled release has no height search to control).
    scheme : {"midpoint", "backward_euler"}
        A frictional pad's load steps: the implicit midpoint rule (second
        order where no contact changes state, :mod:`~fe_contact.stepping.midpoint`)
        or backward Euler (first order); :func:`~fe_contact.stepping.derivatives.rollout_derivatives`
        differentiates either as it runs.  A bonded pad's lift is displacement control either way.
    """

    mode: str
    steps: int
    max_steps: int | None = None
    height: float = 0.0
    away: tuple = (0.0, 0.0)
    error_tol: None = None
    scheme: str = "midpoint"

    def __post_init__(self):
        if self.mode == "open":
            raise ValueError(OPEN_REMOVED)
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("steps", "max_steps"):
            v = getattr(self, name)
            if v is None and name == "max_steps":  # derived from steps (above MAX_STEPS for the largest steps)
                object.__setattr__(self, "max_steps", 2 * int(self.steps) + PUT_DOWN_STEPS)
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_STEPS:
                raise ValueError(f"{name} must be an integer in [1, {MAX_STEPS}], got {v!r}")
        if self.error_tol is not None:
            raise ValueError(ERROR_TOL_REMOVED)
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {SCHEMES}, got {self.scheme!r}")
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
        self.taken = 0
        self.load_step = 0  # a frictional pad's load steps taken
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

    def midpoint(self, command) -> bool:
        """Whether ``command`` is taken by the implicit midpoint rule
        (:mod:`fe_contact.stepping.midpoint`): a frictional pad's load step to a load
        above zero under ``Release.scheme = "midpoint"``; every other step is
        :func:`fe_contact.stepping.step.step` (backward Euler)."""
        return self.release.scheme == "midpoint" and isinstance(command, PadLoad) and command.load > 0

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

    def _pad_lift(self, j: int, state: State, report: StepReport | None):
        """The next step of a frictional pad's release: the pad's load ``P_k``
        of :func:`pad_load_schedule` (:class:`PadLoad`, its height solved for),
        ``k = 1 .. steps``; then, the pad open, the rise and one settle step
        (:meth:`_rise`)."""
        current = self.loaded_pad if report is None else -float(report.upper_force[2])
        while self.load_step < self.release.steps and self.loaded_pad > 0:
            self.load_step += 1
            load, d_loaded, d_weight = pad_load_schedule(self.loaded_pad, self.weight, self.load_step,
                                                         self.release.steps)
            if load < current or load == 0:  # a step that ended past a jump of the load skips the loads above
                self.height_partials = {"load": (load, d_loaded, d_weight)}  # the height where the pad carries it
                return PadLoad(load, tuple(self.retreat))
        return self._rise(state)

    def _put_down(self, state: State, report: StepReport) -> Command | None:
        """The next step of the search for the height where the plate carries
        nothing (see the module docstring): regula falsi on the bracket of the
        lowest height where it pulls (``F > 0``; off the floor ``F = W``) and
        the highest where it pushes, bisecting when a step does not halve
        ``|F|``; below the first bracket, the own-weight compression."""
        h, force = float(state.upper_translation[2]), float(report.upper_force[2])
        if isinstance(report.command, LetGo):
            return None
        if abs(force) <= 0.1 * SETTLE_FORCE * self.weight and np.linalg.norm(report.upper_force) <= \
                SETTLE_FORCE * self.weight:
            return None
        if abs(force) <= LET_GO_FORCE * self.weight and np.linalg.norm(report.upper_force[:2]) > \
                SETTLE_FORCE * self.weight:  # carrying nothing vertically, the pad holds the block in the plane
            self.height_partials = {}
            return LetGo()
        points, touching = self.contact_points, report.normal_force > LIFT_TOL * self.weight
        slow = bool(points) and points[-1][2] and touching and abs(force) > 0.5 * abs(points[-1][1])
        points.append((h, force, touching))
        target, self.height_partials = put_down_target(points, self.weight, self.axial_stiffness, slow, LIFT_TOL)
        return self._along(target - h)


def pad_load_schedule(loaded: float, weight: float, k: int, steps: int) -> tuple[float, float, float]:
    """The pad's load after ``k`` of ``steps`` load steps, N, and its partial
    derivatives by the loaded load ``P_0`` and the weight ``W``: ``P_k`` is
    uniform in

        phi(P) = (1 - w) P / P_0 + w log(1 + P / c) / log(1 + P_0 / c),     c = LOAD_FLOOR W,

    ``phi(P_k) = 1 - k / steps`` (``w = LOAD_LOG_WEIGHT``): half the steps
    uniform in the load, half uniform in its logarithm down to ``c``, where a
    pad stickier than the floor lets go (its friction ``mu_p P`` falls to the
    floor's ``mu_f (P + W)`` at ``P = mu_f W / (mu_p - mu_f)``, 1e-2 W for a pad
    100 x the floor's); ``P_steps = 0``.  Measured (docs/release.md): uniform
    load steps put the rest of a pad 100 x the floor's 13.6 % of the lag from
    the bonded lift at 8 steps."""
    if k >= steps:
        return 0.0, 0.0, 0.0
    c = LOAD_FLOOR * weight
    w, span = LOAD_LOG_WEIGHT, math.log1p(loaded / c)
    phi = lambda p: (1 - w) * p / loaded + w * math.log1p(p / c) / span  # noqa: E731
    target = 1.0 - k / steps
    load = brentq(lambda p: phi(p) - target, 0.0, loaded, xtol=1e-15 * loaded, rtol=4 * np.finfo(float).eps)
    # implicit derivatives of phi(P_k; P_0, c) = target
    d_load = (1 - w) / loaded + w / ((c + load) * span)
    d_span_loaded, d_span_c = 1.0 / (c + loaded), -loaded / (c * (c + loaded))
    log_term = math.log1p(load / c)
    d_loaded = -(1 - w) * load / loaded**2 - w * log_term / span**2 * d_span_loaded
    d_c = -w * load / (c * (c + load) * span) - w * log_term / span**2 * d_span_c
    return load, -d_loaded / d_load, -d_c * LOAD_FLOOR / d_load


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


def rest_check(model: Model, state: State, report: StepReport, schedule: ReleaseSchedule) -> Rest:
    """:class:`Rest` of ``state``, the end of a release (``report`` its last
    step's) run by ``schedule``; the one more step, from ``state`` (not
    modified), is :func:`fe_contact.stepping.step.step`.

    The one more step is judged by its last iterate, converged or not: a null
    step of a stress-free block in the air has no force scale but rounding,
    and its Newton loop cannot meet a tolerance relative to that; its iterate
    is accepted when it is in equilibrium by the same absolute measure as the
    state."""
    scale = schedule.force_scale
    let_go = isinstance(report.command, LetGo)  # a bonded pad that opened: nothing holds the face
    held = model.pad is None and not let_go
    pad, imbalance = _balance(model, state.displacement, state.reaction, held, report.upper_force)
    _, further = step(model, state, LetGo() if let_go else Command())
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
    pad = f[model.held_nodes].sum(axis=0) if held else np.asarray(upper_force, dtype=float)
    if held:
        f[model.held_nodes] = 0.0
    if not np.all(np.isfinite(f)):
        return pad, np.inf
    return pad, float(np.linalg.norm(f, axis=1).max())
