"""The one stepping loop: a sequence of commands, then optionally a release whose
commands are chosen one at a time after the last report.

:class:`StepSequence` is iterated by :func:`run`, :func:`run_release`, :func:`release_to_rest` and every
caller that wants to see each step as it happens (``pushplan``'s driver feeds its
observers from it).  A step that does not converge ends the sequence (its report
is the last one; the state stays the last good one), unless ``stop_on_failure`` is
False.
"""

from __future__ import annotations

import time

import numpy as np

from .command import PadLoad
from .model import Model, State, StepReport, initial_state
from .pad_load import pad_normal_load
from .predictor import load_path_guess
from .release import Release, ReleaseSchedule, rest_check
from .midpoint import closed_contacts, extrapolated, extrapolation_fraction, midpoint_half, partial_state, two_halves
from .step import step


class StepSequence:
    """Iterate ``(state, report)`` over the steps of ``commands`` and then of ``release``.

    Parameters
    ----------
    model : Model
    commands : sequence of Command
    state : State, optional
        Start state (default: the undeformed block); not modified.
    release : Release, optional
        Let go of the block after the commands (:class:`ReleaseSchedule`).
    loaded : StepReport, optional
        The loaded step's report, for a release that starts from ``state``
        without commands before it (default: the last command's report).
    local_problem_hook : callable, optional
        Passed to every :func:`~fe_contact.stepping.step.step`.
    consume_start : bool, optional
        Whether the first step may release ``state``'s cached tangent (see
        :func:`~fe_contact.stepping.step.step`); default: only if the sequence
        made the start state itself.  Later states are the sequence's own.
    stop_on_failure : bool
        End after a step that did not converge.
    guesses : sequence of StepGuess or None, optional
        Where the Newton loop of ``commands[i]`` starts (``guesses[i]``, see
        :func:`~fe_contact.stepping.step.step`); commands past its end and the
        release's steps start from the predictor, a pad's load steps from the last
        load step's path extrapolated in the load (:meth:`_load_guess`).

    Attributes
    ----------
    state : State
        The state after the last step (the last good one: a failed step keeps its start).
    reports : list of StepReport
        Every step's report so far.
    schedule : ReleaseSchedule or None
        The release's, once it has begun.
    """

    def __init__(self, model: Model, commands=(), state: State | None = None, *, release: Release | None = None,
                 loaded: StepReport | None = None, local_problem_hook=None, consume_start: bool | None = None,
                 stop_on_failure: bool = True, guesses=()):
        self.model, self.commands, self.release, self.loaded = model, tuple(commands), release, loaded
        self.guesses = tuple(guesses)
        self.hook, self.stop_on_failure = local_problem_hook, stop_on_failure
        self.consume_start = state is None if consume_start is None else consume_start
        self.state = initial_state(model) if state is None else state
        self.reports: list[StepReport] = []
        self.schedule: ReleaseSchedule | None = None
        self._path: tuple[State, State] | None = None  # the last load step's path (two states on it)

    def __iter__(self):
        for i, command in enumerate(self._commands()):
            consume = self.consume_start or i > 0
            if self.schedule is not None and self.schedule.midpoint(command):  # a pad's load step, midpoint rule
                self.state, report = self._midpoint(command, consume)
            else:
                guess = self.guesses[i] if i < min(len(self.guesses), len(self.commands)) else None
                if isinstance(command, PadLoad):
                    guess = self._load_guess(self.state, command.load)
                start = self.state
                self.state, report = self._step(self.model, self.state, command, consume=consume, guess=guess)
                self._path = (start, self.state) if isinstance(command, PadLoad) and report.converged else None
            self.reports.append(report)
            yield self.state, report
            if not report.converged and self.stop_on_failure:
                return

    def _midpoint(self, command, consume: bool):
        """A pad's load step by the implicit midpoint rule (:mod:`~fe_contact.stepping.midpoint`):
        the half step, extrapolated by the fraction ``w`` of it that stays admissible
        (``midpoint.extrapolation_fraction``), and where ``w < 1`` a second backward-Euler
        step from there to the end's load; both solves by :meth:`_step` (a recording
        sequence records them): at most two a load step."""
        t0, start = time.perf_counter(), self.state
        half = midpoint_half(self.model, start, command)
        middle, first = self._step(self.model, start, half, consume=consume, guess=self._load_guess(start, half.load))
        self._path = (start, middle) if first.converged else None
        if not first.converged:
            return middle, first
        w = extrapolation_fraction(self.model, start, middle, first, half.load)
        if w == 1.0:
            end = extrapolated(self.model, start, command, middle, first, t0)
        else:
            ahead = partial_state(start, middle, w)
            self._path = (middle, ahead) if w > 0 else self._path
            last, second = self._step(self.model, ahead, command, consume=True,
                                      guess=self._load_guess(ahead, command.load))
            if not second.converged:
                self._path = None
                return middle, second
            end = two_halves(start, first, last, second, w)
        self._path = (middle, end[0])
        return end

    def _load_guess(self, start: State, load: float):
        """The start of a pad's load step from ``start`` to ``load`` (N): the last
        load step's path, if it ended at ``start`` and no contact opened or closed
        along it (the path is smooth in the load between contact changes, not
        across one), extrapolated in the load
        (:func:`~fe_contact.stepping.predictor.load_path_guess`), else None."""
        if self._path is None or self._path[1] is not start:
            return None
        before, after = self._path
        if np.any(closed_contacts(before.reaction) != closed_contacts(after.reaction)):
            return None
        return load_path_guess(before, after, (pad_normal_load(self.model, before), pad_normal_load(self.model, after)),
                               load)

    def _step(self, model: Model, state: State, command, consume: bool = False, guess=None):
        """:func:`~fe_contact.stepping.step.step` with the sequence's local-problem hook."""
        return step(model, state, command, self.hook, consume=consume, guess=guess)

    def _commands(self):
        """The commands, then the release's, each chosen after the last report."""
        yield from self.commands
        if self.release is None:
            return
        loaded = self.reports[-1] if self.reports else self.loaded
        self.schedule = ReleaseSchedule(self.model, self.release, self.state, loaded)
        while (command := self.schedule.next_command(self.state, self.reports[-1] if self.reports else None)) \
                is not None:
            yield command


def run(model: Model, commands, state: State | None = None, stop_on_failure: bool = True):
    """Apply a sequence of commands (:class:`StepSequence`).

    Returns
    -------
    state : State
        Final state (the last good one if a step failed).
    reports : list[StepReport]
    """
    sequence = StepSequence(model, commands, state, consume_start=False, stop_on_failure=stop_on_failure)
    for _ in sequence:
        pass
    return sequence.state, sequence.reports


def run_release(model: Model, state: State, release: Release, loaded: StepReport | None = None):
    """Step ``model`` from ``state`` through ``release`` (:class:`StepSequence`);
    ``loaded`` is the report of the loaded step before it.

    Returns the final state and the reports of the release steps.
    """
    state, reports, _ = release_to_rest(model, state, release, loaded, check=False)
    return state, reports


def release_to_rest(model: Model, state: State, release: Release, loaded: StepReport | None = None,
                    check: bool = True):
    """:func:`run_release`, then :func:`~fe_contact.stepping.release.rest_check` of
    where it ended (None without ``check``, or if the release took no step).

    Returns
    -------
    state : State
    reports : list of StepReport
    rest : Rest or None
    """
    sequence = StepSequence(model, (), state, release=release, loaded=loaded, consume_start=True)
    for _ in sequence:
        pass
    reports = sequence.reports
    rest = rest_check(model, sequence.state, reports[-1], sequence.schedule) if check and reports else None
    return sequence.state, reports, rest
