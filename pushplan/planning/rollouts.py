"""FE rollouts of planned commands: the FE model on one mesh, pressed once, every
rollout a :func:`pushplan.run.drive` run branching from the pressed state."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from fe_contact import Command, Model, Release, State, StepGuess, StepReport, rollout_derivatives

from ..config.commands import PLANAR_COMPONENTS, planar_commands
from ..errors import SolverFailure
from ..run import Run, StepSummary, drive


class _EndTangents:
    """A :func:`drive` observer: the tangent each converged step ended with (its state's
    cached one, taken before the next step may release it; None for a failed step)."""

    def __init__(self):
        self.values = []

    def step(self, run: Run, report: StepReport) -> None:
        self.values.append(run.state.tangent.value if report.converged else None)


class PlanningError(SolverFailure):
    """An FE rollout failed (the step's status and message are quoted)."""


@dataclass(frozen=True)
class Pressed:
    """The state after the press, with the press steps' reports and summaries."""

    state: State
    reports: tuple[StepReport, ...]
    steps: tuple[StepSummary, ...]


@dataclass(frozen=True)
class Rollout:
    """An FE rollout of K planned commands from the pressed state.

    Attributes
    ----------
    commands : ndarray, shape (K, 3)
        ``(dx, dy, dtheta)``, m and rad.
    lower, upper : ndarray, shape (K + 1, 3)
        Face poses ``(x, y, yaw)``, m and rad; row 0 after the press.
    reports, steps : tuples of K
        The step reports and their summaries.
    wall_time : float
        s.
    rest : ndarray, shape (3,), or None
        Lower-face pose ``(x, y, yaw)`` at rest after the release (None without one).
    release_reports : tuple
        The release steps' reports.
    pad_slip : float
        Largest in-plane distance over the commands between the pad's
        commanded position and the block's upper-face centroid, m: how far a
        frictional pad slid on the upper face (0 for a bonded pad, which the
        upper face follows; the reduced model assumes it does).
    nondifferentiable : str
        For a rollout with derivatives: why some of them do not exist (a contact
        at a transition of the contact law, :mod:`fe_contact.stepping.transitions`), or "";
        the inputs named are the commands' ``dx[k]``, ``dy[k]``, ``dtheta[k]`` (k from 0),
        the columns of the Jacobians (:func:`planar_columns`: a transition along ``dz``
        alone, which is not commanded, is left out).
    loaded_jacobian : ndarray, shape (3, K, 3), or None
        For a rollout with derivatives: ``d lower[-1] / d commands``, the final loaded
        pose's (m/m, m/rad, rad/m, rad/rad), NaN where it does not exist.
    """

    commands: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    reports: tuple[StepReport, ...]
    steps: tuple[StepSummary, ...]
    wall_time: float
    rest: np.ndarray | None = None
    release_reports: tuple[StepReport, ...] = ()
    pad_slip: float = 0.0
    nondifferentiable: str = ""
    loaded_jacobian: np.ndarray | None = None

    def final(self, target_state: str = "loaded") -> np.ndarray:
        """The final lower-face pose (3,) loaded (after the last command) or at rest."""
        if target_state == "rest":
            if self.rest is None:
                raise ValueError("this rollout has no release: no rest pose")
            return self.rest
        return self.lower[-1]


def planar_columns(K: int) -> list[int]:
    """The columns of ``dx[k]``, ``dy[k]``, ``dtheta[k]`` (k < K) among the inputs of
    :func:`fe_contact.rollout_derivatives` (``dx, dy, dz, dtheta`` per command): the
    commands a planner (and a service client) sends; ``dz`` is not one of them (0)."""
    return [4 * k + c for k in range(K) for c in PLANAR_COMPONENTS]


class FeRollouts:
    """The FE model on one mesh, pressed once; every rollout branches from the start
    state (``drive`` never mutates its start state): the pressed block, or the state
    the executed commands left (:meth:`advance`).  Counts rollouts; times the press and
    the executed commands (``press_time``, s).

    ``after``: commands already executed after the press (re-planning from a measured
    state); they are applied once after the press, and rollout poses are then relative
    to the pose they leave (row 0 is zero).

    ``warm_steps``: every rollout's Newton loops start from the last rollout's converged
    steps of the same pushes (:class:`fe_contact.StepGuess`, counted from the press: a
    re-plan's rollout after an executed push starts each step from the step one push
    later of the rollout before).  The answers are the same to the solver's tolerances
    (``newton_tol``, ``local_tol``), not bit for bit; ``guessed_steps`` counts the steps
    that started from a guess.  The guesses hold the tangent each step ended with: one
    factorised tangent per push alive (a planning mesh's)."""

    def __init__(self, model: Model, press: tuple[Command, ...], label: str, release: Release | None = None,
                 after: tuple[Command, ...] = (), keep_first: bool = False, warm_steps: bool = False):
        self.model = model
        self.press = tuple(press)
        self.after = tuple(after)
        self.label = label
        self.release = release
        self.count = 0
        self.press_time = 0.0
        self._at_rest: Pressed | None = None
        self._pressed: Pressed | None = None
        # keep_first: the last rollout's first step, its start and command, for :meth:`advance`
        self.keep_first = keep_first and model.pad is None
        self._first: tuple[Pressed, Command, Run] | None = None
        # warm_steps: the last rollout's converged steps by push (0: the first after the press)
        self.warm_steps = warm_steps
        self._guesses: dict[int, StepGuess] = {}
        self.guessed_steps = 0

    @property
    def relative(self) -> bool:
        """Whether rollouts start after executed commands (poses relative to their end)."""
        return bool(self.after)

    def _drive(self, commands, state: State | None = None, keep_states: bool = False,
               release: Release | None = None, guesses=(), ended: _EndTangents | None = None) -> Run:
        """:func:`drive`, its steps started from ``guesses``, the tangents they end with
        added to ``ended``; PlanningError if a step fails."""
        run = drive(self.model, commands, state, keep_states=keep_states, release=release, guesses=guesses,
                    observers=() if ended is None else (ended,))
        if not run.completed:
            f = run.summary.failure
            raise PlanningError(f"FE step {f.step} on the {self.label} mesh failed ({f.status}): {f.message}")
        return run

    def at_rest(self) -> Pressed:
        """The state after the press (computed once).

        Raises
        ------
        PlanningError
            A press step did not converge.
        """
        if self._at_rest is None:
            t0 = time.perf_counter()
            run = self._drive(self.press)
            self._at_rest = Pressed(run.state, tuple(run.reports), tuple(run.summary.steps))
            self.press_time += time.perf_counter() - t0
        return self._at_rest

    def pressed(self) -> Pressed:
        """The start of the rollouts: the state after the press and the executed commands
        (computed once, then moved by :meth:`advance`); ``reports`` / ``steps`` all of them.

        Raises
        ------
        PlanningError
            A step did not converge.
        """
        if self._pressed is None:
            self._pressed = self._advanced(self.at_rest(), self.after)
        return self._pressed

    def _advanced(self, start: Pressed, commands) -> Pressed:
        if not commands:
            return start
        t0 = time.perf_counter()
        first, self._first = self._first, None
        if first is not None and first[0] is start and _same_bits(first[1], commands[0]):
            run = first[2]  # the step the last rollout took from here: the same state, computed once
            start = Pressed(run.state, start.reports + tuple(run.reports), start.steps + tuple(run.summary.steps))
            commands = commands[1:]
        if commands:
            run = self._drive(tuple(commands), start.state)
            start = Pressed(run.state, start.reports + tuple(run.reports), start.steps + tuple(run.summary.steps))
        self.press_time += time.perf_counter() - t0
        return start

    def advance(self, commands) -> None:
        """Execute ``commands`` (fe_contact Commands) from the start state: one FE step
        each, never re-run from the press; later rollouts start after them.

        Raises
        ------
        PlanningError
            A step did not converge.
        """
        self._pressed = self._advanced(self.pressed(), tuple(commands))
        self.after += tuple(commands)

    @property
    def exact(self) -> bool:
        """Whether :meth:`rollout_with_jacobian` applies: no release after the
        commands, or one straight up (a release with a retreat is not differentiated)."""
        return self.release is None or not any(self.release.away)

    def rollout_with_jacobian(self, commands: np.ndarray, release: bool = True) -> tuple[Rollout, np.ndarray]:
        """:meth:`rollout` (with the release, if any and ``release``) and the exact Jacobian
        (3, K, 3) of the final lower-face pose ``(x, y, yaw)``, the rest's after a release, with
        respect to the commands ``(dx, dy, dtheta)`` (:func:`fe_contact.rollout_derivatives`,
        the same converged steps); the final loaded pose's is the rollout's ``loaded_jacobian``.
        ``upper`` holds the plate's pose (the upper face's, for the rigid gripper).  Where a derivative does not exist (a contact at a
        transition of the contact law) its entries are NaN and the rollout's
        ``nondifferentiable`` says why.  A frictional pad's release is differentiated as it
        is run (midpoint or backward-Euler load steps, ``Release.scheme``): one rollout.

        Raises
        ------
        PlanningError
            An FE step did not converge, or the block did not settle after the release.
        """
        pressed = self.pressed()
        t0 = time.perf_counter()
        release = self.release if release else None
        result = rollout_derivatives(self.model, planar_commands(commands), state=pressed.state, parameters=(),
                                     release=release)
        if not result.converged:
            raise PlanningError(f"FE rollout on the {self.label} mesh failed ({result.status.value}): {result.message}")
        if result.rest is not None and not result.rest.settled:
            raise PlanningError(f"FE rollout on the {self.label} mesh: the block did not settle after the release: "
                                f"{result.rest.reason}")
        K, start = len(commands), pressed.reports[-1]
        lower = np.vstack([[*start.lower_centroid[:2], start.lower_yaw], result.outputs[:K, :3]])
        upper = np.vstack([pressed.state.plate, [r.plate for r in result.reports[:K]]])
        rest = None if release is None else result.outputs[-1, :3].copy()
        if self.relative:
            origin = lower[0].copy()
            lower, upper = lower - origin, upper - upper[0]
            rest = None if rest is None else rest - origin
        self.count += 1
        reports = tuple(result.reports[:K])
        commanded = pressed.state.upper_translation[:2] + np.cumsum(np.asarray(commands, float)[:, :2], axis=0)
        roll = Rollout(np.array(commands, float), lower, upper, reports,
                       tuple(StepSummary.from_report(r) for r in reports), time.perf_counter() - t0, rest,
                       tuple(result.reports[K:]), self._pad_slip_of(commanded, reports), result.nondifferentiable(planar_columns(K)),
                       result.d_commands[K - 1, :3][:, :, PLANAR_COMPONENTS])
        return roll, result.d_commands[-1, :3][:, :, PLANAR_COMPONENTS]

    def rollout(self, commands: np.ndarray, release: bool = True, from_rest: bool = False,
                warm: bool = True) -> Rollout:
        """Apply (K, 3) commands ``(dx, dy, dtheta)`` from the start state (``from_rest``:
        from the pressed block at rest, absolute poses), then the release if there is one
        and ``release``.  With :attr:`warm_steps`, ``warm`` rollouts start their steps from
        the last warm rollout's and keep theirs for the next; ``warm=False`` (a client's
        own rollout, a calibration's rotation) neither: its numbers do not depend on the
        rollouts before it, and it leaves the guesses as they were.

        Raises
        ------
        PlanningError
            An FE step did not converge.
        """
        pressed = self.at_rest() if from_rest else self.pressed()
        t0 = time.perf_counter()
        first = (0 if from_rest else len(self.after)) if warm else None  # its first push, from the press
        run = self._drive_from(pressed, planar_commands(commands), self.release if release else None,
                               keep=self.keep_first and not from_rest, first=first)
        K = len(commands)
        loaded = run.reports[:K]
        lower = np.array([[*r.lower_centroid[:2], r.lower_yaw] for r in (pressed.reports[-1], *loaded)])
        upper = np.array([[*s.upper_translation[:2], s.upper_rotation] for s in run.states[:K + 1]])
        rest = run.summary.rest
        rest = None if rest is None else np.array([*rest.lower_centroid[:2], rest.lower_yaw])
        if self.relative and not from_rest:  # poses from the pose the executed commands left
            origin = lower[0].copy()
            lower, upper = lower - origin, upper - upper[0]
            rest = None if rest is None else rest - origin
        wall = time.perf_counter() - t0
        self.count += 1
        return Rollout(np.array(commands, float), lower, upper, tuple(loaded), tuple(run.summary.steps[:K]), wall,
                       rest, tuple(run.reports[K:]), self._pad_slip(run.states[1:K + 1], loaded))

    def _drive_from(self, pressed: Pressed, commands: tuple[Command, ...], release: Release | None,
                    keep: bool, first: int | None = None) -> Run:
        """The run of ``commands`` (then ``release``) from ``pressed`` with every state; with
        ``keep`` its first step is run alone and kept for :meth:`advance` (the state after
        it keeps its factorised tangent, which the next step of one run would release: one
        more tangent alive, a planning mesh's).  A step of a run does not depend on the
        steps after it, so both ways give the same numbers (a release after a single
        command is not split: it starts from the loaded step's report of its own run).
        ``first``: the push ``commands[0]`` is, counted from the press, for :attr:`warm_steps`
        (None: the run neither takes nor leaves guesses)."""
        guesses = self._guessed(first, len(commands))
        ended = _EndTangents() if self.warm_steps and first is not None else None
        if not keep or not commands or (len(commands) == 1 and release is not None):
            run = self._drive(commands, pressed.state, True, release, guesses, ended)
        else:
            one = self._drive(commands[:1], pressed.state, True, None, guesses[:1], ended)
            self._first = (pressed, commands[0], one)
            run = one
            if len(commands) > 1:
                rest = self._drive(commands[1:], one.state, True, release, guesses[1:], ended)
                rest.summary.steps = one.summary.steps + rest.summary.steps
                run = Run(self.model, rest.state, rest.summary, one.reports + rest.reports,
                          one.states + rest.states[1:])
        if ended is not None:
            self._remember(first, commands, run.states, ended.values)
        return run

    def _guessed(self, first: int | None, K: int) -> tuple:
        """The kept steps' guesses for pushes ``first .. first + K - 1`` (None where there is none)."""
        if not self.warm_steps or first is None:
            return ()
        guesses = tuple(self._guesses.get(first + k) for k in range(K))
        self.guessed_steps += sum(g is not None for g in guesses)
        return guesses

    def _remember(self, first: int, commands: tuple[Command, ...], states, tangents) -> None:
        """Keep the converged steps of a rollout (``states``, K + 1 of them, and the
        ``tangents`` the steps ended with) as the guesses of pushes ``first ...``."""
        for k, command in enumerate(commands):
            self._guesses[first + k] = StepGuess.of(self.model, states[k], command, states[k + 1], tangents[k])

    def _pad_slip(self, states, reports) -> float:
        """:attr:`Rollout.pad_slip` of loaded steps' end ``states`` and ``reports``, m."""
        return self._pad_slip_of([s.upper_translation[:2] for s in states], reports)

    def _pad_slip_of(self, commanded, reports) -> float:
        """:attr:`Rollout.pad_slip` of the commanded positions ``(x, y)`` of the pad
        after each loaded step and their ``reports``, m."""
        if self.model.pad is None or not reports:
            return 0.0
        return float(max(np.hypot(*(np.asarray(c) - r.upper_centroid[:2]))
                         for c, r in zip(commanded, reports, strict=True)))


def _same_bits(a: Command, b: Command) -> bool:
    """Whether two commands are the same floats bit for bit (``-0.0`` is not ``0.0``)."""
    return np.array([a.dx, a.dy, a.dz, a.dtheta]).tobytes() == np.array([b.dx, b.dy, b.dz, b.dtheta]).tobytes()
