"""The one driver of ``fe_contact`` through a sequence of commands, on fe_contact's
one stepping loop (:class:`fe_contact.StepSequence`).

Every caller (``simulate``, the planner's rollouts, the MuJoCo bridge, the studies)
runs its steps through :func:`drive`; what it does with each step is an *observer*:

    class Observer:
        def step(self, run: Run, report: StepReport) -> None: ...      # after every step
        def local_problem(self, W, q, solution) -> None: ...           # optional: each local solve
        def finish(self, run: Run) -> None: ...                        # optional: after the last step
        def close(self, run: Run) -> None: ...                         # optional: always, last

``run.summary`` is up to date when an observer sees a step.  With a ``release``
(:class:`fe_contact.Release`), its steps follow the commands, each chosen after the
last report (:class:`fe_contact.ReleaseSchedule`); they are steps like any other,
and ``run.summary.rest`` describes where the block came to rest and whether it is
settled (:func:`fe_contact.rest_check`: the pad unloaded, every node in equilibrium,
one more step moves nothing).  A step that does not
converge ends the run with a :class:`Failure` (its state is not kept); ``drive`` never
turns an exception into a status: ``fe_contact.stepping.step`` reports numerical breakdowns as
statuses itself, so anything raised here is a bug and propagates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fe_contact import Command, Model, Release, State, StepReport, StepSequence, rest_check

from ..config.scenario import pad_friction_dict
from .summary import Failure, RestSummary, RunStatus, RunSummary, StepSummary


@dataclass
class Run:
    """A run in progress or finished.

    Attributes
    ----------
    model : fe_contact.Model
    state : fe_contact.State
        The last good state.
    reports : list of StepReport
        Every step's report, the failed one last if any.
    states : list of State
        With ``keep_states``: the start state, then the state after each converged step.
    summary : RunSummary
    """

    model: Model
    state: State
    summary: RunSummary
    reports: list[StepReport] = field(default_factory=list)
    states: list[State] = field(default_factory=list)

    @property
    def completed(self) -> bool:
        return self.summary.completed

    @property
    def converged_reports(self) -> list[StepReport]:
        return [r for r in self.reports if r.converged]


def _hook(observers):
    targets = [o.local_problem for o in observers if hasattr(o, "local_problem")]
    if not targets:
        return None

    def hook(W, q, solution):
        for target in targets:
            target(W, q, solution)

    return hook


def _call(observers, name: str, run: Run) -> None:
    for o in observers:
        if hasattr(o, name):
            getattr(o, name)(run)


def drive(model: Model, commands, state: State | None = None, *, scenario: dict | None = None,
          observers=(), keep_states: bool = False, release: Release | None = None, guesses=()) -> Run:
    """Apply ``commands`` in order from ``state`` (default: the undeformed block).

    Parameters
    ----------
    model : fe_contact.Model
    commands : sequence of fe_contact.Command
    state : fe_contact.State, optional
        Start state; not modified (a branch point stays usable).
    scenario : dict, optional
        The scenario as run (``Scenario.to_dict()`` with these commands), kept in the summary.
    observers : sequence
        See the module docstring.
    keep_states : bool
        Keep every state in ``run.states``.
    release : fe_contact.Release, optional
        Let go of the block after the commands (see the module docstring).
    guesses : sequence of fe_contact.StepGuess or None, optional
        Where each command's Newton loop starts (:class:`fe_contact.StepSequence`):
        the same answers to the solver's tolerances, in fewer iterations from a close guess.

    Raises
    ------
    TypeError
        A command is not a ``fe_contact.Command`` (a caller's bug: commands from
        files are parsed into ``Command`` by :mod:`pushplan.config.commands`).
    """
    commands = tuple(commands)
    for i, c in enumerate(commands):
        if not isinstance(c, Command):
            raise TypeError(f"commands[{i}] must be a fe_contact.Command, got {type(c).__name__}")
    sequence = StepSequence(model, commands, state, release=release, local_problem_hook=_hook(observers),
                            guesses=guesses)
    run = Run(model=model, state=sequence.state, summary=RunSummary(scenario=scenario or {}),
              states=[sequence.state] if keep_states else [])
    t0 = time.perf_counter()
    try:
        for i, (new_state, report) in enumerate(sequence):
            run.reports.append(report)
            _record(run, new_state, report, keep_states, "command" if i < len(commands) else "release")
            run.summary.elapsed_s = time.perf_counter() - t0
            for o in observers:
                o.step(run, report)
        if run.summary.status != RunStatus.FAILED:
            run.summary.status = RunStatus.COMPLETED
            if release is not None and run.reports:
                rest = rest_check(model, run.state, run.reports[-1], sequence.schedule)
                run.summary.rest = RestSummary.from_report(run.reports[-1], release.mode, rest,
                                                           pad_friction_dict(model.pad), _pad_slip_at_release(run))
                _unsettled_is_a_failure(run.summary, run.reports[-1].step_index)
        run.summary.elapsed_s = time.perf_counter() - t0
        _call(observers, "finish", run)
    finally:
        _call(observers, "close", run)
    return run


def _unsettled_is_a_failure(summary: RunSummary, last_step: int) -> None:
    """A release whose block did not settle ends the run as failed (``summary.json``'s
    ``status`` and ``failure`` say so, as the exit status 3 does): the one place that
    decides, so the file and the exit status cannot disagree."""
    rest = summary.rest
    if rest is not None and not rest.settled:
        summary.status = RunStatus.FAILED
        summary.failure = Failure(rest.step if rest.step is not None else last_step, rest.status,
                                  f"the block did not settle after the release: {rest.reason}")


def _pad_slip_at_release(run: Run) -> float | None:
    """:attr:`RestSummary.pad_slip`: the pad's slip at the last step it still touched."""
    touching = [s.pad_slip for s, r in zip(run.summary.steps, run.converged_reports, strict=True)
                if s.pad_slip is not None and np.any(r.pad_reaction[:, 0] != 0.0)]
    return touching[-1] if touching else (run.summary.steps[-1].pad_slip if run.summary.steps else None)


def _record(run: Run, new_state: State, report: StepReport, keep_states: bool, phase: str) -> None:
    if report.converged:
        run.state = new_state
        run.summary.steps.append(StepSummary.from_report(report, phase, new_state.upper_translation))
        if keep_states:
            run.states.append(new_state)
    else:
        run.summary.failure = Failure(report.step_index, report.status.value, report.message)
        run.summary.status = RunStatus.FAILED
