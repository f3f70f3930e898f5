"""Steps in parts: the halving of a step that fails, and step-doubling error control.

A quasi-static step of a friction problem is a backward-Euler step of the slip
rule (paper eq. 23-30, 42-45 on the increment): its error is first order in the
step, and the path the contacts take within it is the step's straight line.
Where the contact state changes (the pad's load falling to zero, its contacts
and the floor's passing from stick to slip), a step that is too long sets the
answer.  :func:`controlled_step` estimates the error of a step by step doubling
(Hairer, Norsett & Wanner, *Solving ODEs I*, sect. II.4): the step ``U_1`` and two
half steps ``U_2``; for a first-order method ``U_2 - U_exact ~ U_1 - U_2``, so

    e = max_i ||U_1,i - U_2,i||                   (m, over the block's nodes)

is the error of the accepted (two half steps) result.  It is accepted when
``e <= tol * |s| / span`` (error per unit step, ``s`` the step's size and
``span`` the whole motion's, so that the errors summed over the release stay
below ``tol``, m); otherwise each half is controlled in turn.  Refinement thus
happens where the contact state changes and nowhere else.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .model import Command, State, StepReport

MAX_REFINE = 8
"""Step-doubling levels at most (a part at least 2**-8 of the step); deeper, the half steps are accepted."""


def half_command(command: Command) -> Command:
    """Half of a moving command (the same straight path, in two parts)."""
    return Command(dx=command.dx / 2, dy=command.dy / 2, dz=command.dz / 2, dtheta=command.dtheta / 2)


def joined_report(state: State, first: StepReport, second: StepReport, command: Command, message: str,
                  combine=sum) -> StepReport:
    """The report of a step taken in two parts from ``state``: the second
    part's, with the whole ``command``, both parts' slip increments, their
    Newton iterations combined by ``combine`` (``sum``: the cost; ``max``: the
    longest Newton loop), and ``message``."""
    return replace(second, command=command, step_index=state.step_index + 1,
                   newton_iterations=combine((first.newton_iterations, second.newton_iterations)),
                   slip_increment=first.slip_increment + second.slip_increment, message=message)


def controlled_step(model, state: State, command: Command, step, tol: float, span: float,
                    full: tuple[State, StepReport] | None = None, depth: int = 0) -> tuple[State, StepReport]:
    """``command`` from ``state`` with step-doubling error control (module docstring).

    Parameters
    ----------
    model : Model
    state : State
        Not modified.
    command : Command
        A moving command; its size is ``|dz|`` (m), or ``|(dx, dy)|``.
    step : callable
        :func:`fe_contact.stepping.step.step`.
    tol : float
        Error allowed over ``span``, m (> 0).
    span : float
        Size of the whole motion the error is spread over, m (> 0).
    full : (State, StepReport), optional
        The step already taken whole (the half of the level above).

    Returns
    -------
    (State, StepReport)
        The end of the step, and its report (joined over the parts, its
        ``newton_iterations`` the longest Newton loop's).  A part that fails
        stops the refinement there (the coarser result stands); if the half
        steps fail, the whole step's result (converged or failed) is returned.
    """
    full = step(model, state, command) if full is None else full
    half = half_command(command)
    first = step(model, state, half)
    second = step(model, first[0], half) if first[1].converged else first
    if not second[1].converged:  # the error cannot be estimated: the whole step as it is
        return full
    size = abs(command.dz) or float(np.hypot(command.dx, command.dy))
    error = np.inf if not full[1].converged else \
        float(np.linalg.norm(full[0].displacement - second[0].displacement, axis=1).max())
    end, parts = second[0], (first[1], second[1])
    if error > tol * size / span and depth < MAX_REFINE:
        middle, a = controlled_step(model, state, half, step, tol, span, first, depth + 1)
        end_b, b = controlled_step(model, middle, half, step, tol, span, None, depth + 1) if a.converged else (None, a)
        if b.converged:  # else: the two half steps as they are
            end, parts = end_b, (a, b)
    report = joined_report(state, *parts, command, f"converged in parts (error control, {depth + 1} level(s) deep)",
                           combine=max)
    return replace(end, step_index=state.step_index + 1), report
