"""One quasi-static load step, composed of named stages (paper sect. 8, Box 3 / Box 4):

    pose, U_0 = commanded_pose(state, command), predictor(model, state, command)
    eq        = equilibrium(model, state, U_0)      Newton loop with the contact
                                                    solve per iteration and the
                                                    tangent policy
    report    = measure(model, state, command, eq)  StepReport of the last iterate
    state'    = next_state(state, eq, pose, report) if eq converged, else state

Stages live in their own modules: :mod:`fe_contact.stepping.predictor` (start of the
loop), :mod:`fe_contact.stepping.newton` (equilibrium loop), :mod:`fe_contact.stepping.tangent`
(factorised tangent, flexibility matrix ``W``, when to refresh them),
:mod:`fe_contact.stepping.measure` (the report).  Numerical breakdowns come back as a
failed report with its :class:`~fe_contact.stepping.model.Status`; only invalid
arguments raise ``ValueError``.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .gripper import compliant_step
from .held import held_step, joined_report, let_go_step, next_state
from .command import LetGo, PadLoad
from .model import Command, Model, State, StepReport
from .pad_load import load_step
from .predictor import StepGuess, commanded_pose


def step(model: Model, state: State, command: Command, local_problem_hook=None, *,
         consume: bool = False, guess: StepGuess | None = None) -> tuple[State, StepReport]:
    """Apply one load step.

    Parameters
    ----------
    model : Model
    state : State
        State at the start of the step (not modified).
    command : Command or PadLoad
        Rigid motion increment of the upper face, or (a frictional pad only)
        the pad's load at the end of the step, its height solved for
        (:mod:`fe_contact.stepping.pad_load`), or (a bonded pad)
        :class:`~fe_contact.stepping.command.LetGo`: the pad opens, the upper
        face is free (:func:`~fe_contact.stepping.held.let_go_step`).
    local_problem_hook : callable, optional
        Called as ``hook(W, q, solution)`` after every local contact solve with
        the problem exactly as the local solver got it: ``u = W r + q`` in the
        local frames, divided by the mean diagonal compliance so that ``W`` is
        dimensionless and ``q``, ``u`` are in N like ``r``; ``solution`` is the
        :class:`~fe_contact.contact.local_solver.LocalSolution`.  For exporting the
        problems (FCLIB) or studying solvers; the hook must not modify them.
    consume : bool
        The caller will not step from ``state`` again (a run that only goes
        forward): when the step refreshes the tangent, ``state``'s cached one is
        released first (``state.tangent.release()``): one factorised tangent alive,
        not two (4.5 GB each at 2e5 dofs); the same results.  False to branch from ``state``.
    guess : StepGuess, optional
        The Newton loop's start (:class:`~fe_contact.stepping.predictor.StepGuess`):
        the same answer to the tolerances, in fewer iterations from a close guess.
        The rigid drive and a pad's :class:`PadLoad` (a compliant gripper's pose ignores it).

    Returns
    -------
    new_state : State
        State at the end of the step; the input ``state`` when the step failed.
    report : StepReport
        Measurements of the step; ``report.status`` tells whether it converged and
        which stage failed otherwise (a singular tangent, non-finite numbers
        and the like are statuses, not exceptions).

    Raises
    ------
    ValueError
        An argument of the wrong type, or a state of the wrong sizes or not finite.
    """
    _check_arguments(model, state, command, guess)
    t0 = time.perf_counter()
    if isinstance(command, LetGo):  # a bonded pad opens: the upper face free
        return let_go_step(model, state, command, t0, local_problem_hook, consume)
    if model.pad is not None:  # a pose or a load (PadLoad); a compliant gripper's plate solved in the loop
        return _split_step(model, state, command, t0, local_problem_hook, 0, guess)
    if not model.gripper.rigid:
        return compliant_step(model, state, command, t0, local_problem_hook, consume)
    translation, rotation = commanded_pose(state, command)
    eq, report = held_step(model, state, command, translation, rotation, t0, local_problem_hook, consume,
                           guess=guess)
    if not report.converged:
        return state, report
    return next_state(state, eq, translation, rotation, report), report


def half_command(command: Command) -> Command:
    """Half of a moving command (the same straight path, in two parts)."""
    return Command(dx=command.dx / 2, dy=command.dy / 2, dz=command.dz / 2, dtheta=command.dtheta / 2)


MAX_SPLITS = 4
"""A frictional pad's step that fails is split in halves, at most this many times over."""


def _pad_step(model: Model, state: State, command, t0: float, hook, guess=None):
    """One step with a frictional pad: a commanded pose, or a load (:class:`PadLoad`,
    the pad's height solved for, from ``guess`` if given; a compliant gripper's plate pose solved for).
    Returns ``(eq, report, translation, rotation, plate)`` (plate None: the commanded one)."""
    if isinstance(command, PadLoad) or not model.gripper.rigid:
        return load_step(model, state, command, t0, hook, guess)
    translation, rotation = commanded_pose(state, command)
    return (*held_step(model, state, command, translation, rotation, t0, hook), translation, rotation, None)


def _halves(state: State, command):
    """The two parts of a step: half the motion twice, or the load half way, then the whole load."""
    if isinstance(command, PadLoad):
        current = float(state.reaction[state.slip_path.size:, 0].sum())  # the pad's load now
        return replace(command, load=0.5 * (current + command.load)), command
    half = half_command(command)
    return half, half


def _split_step(model: Model, state: State, command, t0: float, hook, depth: int, guess=None):
    """A step with a frictional pad; if it fails, two steps of half the command
    (or of the load half way, then the whole) each (recursively, up to
    :data:`MAX_SPLITS` levels): the pad's contacts changing state within a
    step can defeat the local solvers (measured: a pad of mu 60 opening), and
    half the motion is a finer path of the same friction law.  The report of a
    split step is its last part's, with the whole motion, the iterations of
    all parts and a message saying so.  ``guess`` starts the whole step's Newton loop (not its parts')."""
    eq, report, translation, rotation, plate = _pad_step(model, state, command, t0, hook, guess)
    if report.converged:
        return next_state(state, eq, translation, rotation, report, plate=plate), report
    if depth >= MAX_SPLITS:
        return state, report
    first_part, second_part = _halves(state, command)
    middle, first = _split_step(model, state, first_part, t0, hook, depth + 1)
    if not first.converged:
        return state, first
    end, second = _split_step(model, middle, second_part, t0, hook, depth + 1)
    if not second.converged:
        return state, second
    taken = command if isinstance(command, Command) else Command(*(end.upper_translation - state.upper_translation))
    report = joined_report(state, first, second, taken, f"converged in parts (half steps, {depth + 1} level(s) deep)")
    return replace(end, step_index=state.step_index + 1), report


def _check_arguments(model, state, command, guess=None) -> None:
    """ValueError naming the offending argument, type or size."""
    if not isinstance(model, Model):
        raise ValueError(f"model must be a Model, got {type(model).__name__}")
    if not isinstance(state, State):
        raise ValueError(f"state must be a State, got {type(state).__name__}")
    if isinstance(command, PadLoad) and model.pad is None:
        raise ValueError("a PadLoad command needs a frictional pad (Model(pad=Friction(...)))")
    if isinstance(command, LetGo) and model.pad is not None:
        raise ValueError("a LetGo command is a bonded pad's (a frictional pad opens by PadLoad(0))")
    if not isinstance(command, (Command, PadLoad)):
        raise ValueError(f"command must be a Command, got {type(command).__name__}")
    expected = {"displacement": (model.mesh.n_nodes, 3), "reaction": (model.n_contacts, 3),
                "upper_translation": (3,), "slip_path": (model.n_lower,)}
    for name, shape in expected.items():
        a = getattr(state, name)
        if a.shape != shape:
            raise ValueError(f"state.{name} has shape {a.shape}, model needs {shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"state.{name} must be finite")
    if not np.isfinite(state.upper_rotation):
        raise ValueError(f"state.upper_rotation must be finite, got {state.upper_rotation}")
    if guess is not None:
        guess.check(model)
