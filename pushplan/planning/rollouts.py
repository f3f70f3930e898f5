"""FE rollouts of planned commands: the FE model on one mesh, pressed once, every
rollout a :func:`pushplan.run.drive` run branching from the pressed state."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from fe_contact import Command, Model, Release, State, StepReport

from ..config.commands import planar_commands
from ..errors import SolverFailure
from ..run import Run, StepSummary, drive


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
    """

    commands: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    reports: tuple[StepReport, ...]
    steps: tuple[StepSummary, ...]
    wall_time: float
    rest: np.ndarray | None = None
    release_reports: tuple[StepReport, ...] = ()

    def final(self, target_state: str = "loaded") -> np.ndarray:
        """The final lower-face pose (3,) loaded (after the last command) or at rest."""
        if target_state == "rest":
            if self.rest is None:
                raise ValueError("this rollout has no release: no rest pose")
            return self.rest
        return self.lower[-1]


class FeRollouts:
    """The FE model on one mesh, pressed once; every rollout branches from the pressed
    state (``drive`` never mutates its start state).  Counts rollouts; times the press.

    ``after``: commands already executed after the press (re-planning from a measured
    state); they are applied once with the press, and rollout poses are then relative
    to the pose they leave (row 0 is zero)."""

    def __init__(self, model: Model, press: tuple[Command, ...], label: str, release: Release | None = None,
                 after: tuple[Command, ...] = ()):
        self.model = model
        self.press = tuple(press) + tuple(after)
        self.relative = bool(after)
        self.label = label
        self.release = release
        self.count = 0
        self.press_time = 0.0
        self._pressed: Pressed | None = None

    def _drive(self, commands, state: State | None = None, keep_states: bool = False,
               release: Release | None = None) -> Run:
        run = drive(self.model, commands, state, keep_states=keep_states, release=release)
        if not run.completed:
            f = run.summary.failure
            raise PlanningError(f"FE step {f.step} on the {self.label} mesh failed ({f.status}): {f.message}")
        return run

    def pressed(self) -> Pressed:
        """The state after the press (computed once).

        Raises
        ------
        PlanningError
            A press step did not converge.
        """
        if self._pressed is None:
            t0 = time.perf_counter()
            run = self._drive(self.press)
            self._pressed = Pressed(run.state, tuple(run.reports), tuple(run.summary.steps))
            self.press_time = time.perf_counter() - t0
        return self._pressed

    def rollout(self, commands: np.ndarray, release: bool = True) -> Rollout:
        """Apply (K, 3) commands ``(dx, dy, dtheta)`` after the press, then the
        release if there is one and ``release``.

        Raises
        ------
        PlanningError
            An FE step did not converge.
        """
        pressed = self.pressed()
        t0 = time.perf_counter()
        run = self._drive(planar_commands(commands), pressed.state, keep_states=True,
                          release=self.release if release else None)
        K = len(commands)
        loaded = run.reports[:K]
        lower = np.array([[*r.lower_centroid[:2], r.lower_yaw] for r in (pressed.reports[-1], *loaded)])
        upper = np.array([[*s.upper_translation[:2], s.upper_rotation] for s in run.states[:K + 1]])
        rest = run.summary.rest
        rest = None if rest is None else np.array([*rest.lower_centroid[:2], rest.lower_yaw])
        if self.relative:  # poses from the pose the executed commands left
            origin = lower[0].copy()
            lower, upper = lower - origin, upper - upper[0]
            rest = None if rest is None else rest - origin
        wall = time.perf_counter() - t0
        self.count += 1
        return Rollout(np.array(commands, float), lower, upper, tuple(loaded), tuple(run.summary.steps[:K]), wall,
                       rest, tuple(run.reports[K:]))
