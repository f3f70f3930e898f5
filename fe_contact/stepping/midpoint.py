"""A frictional pad's load step by the implicit midpoint rule (the release's default
scheme, ``Release.scheme = "midpoint"``): a backward-Euler load step
(:func:`~fe_contact.stepping.step.step` with a :class:`PadLoad`, solved by
:mod:`fe_contact.stepping.pad_load`) to the mid load, extrapolated to the end.

    P_m = (P_a + P_b) / 2,    S_m = BE(S_a, P_m),    S_b = 2 S_m - S_a

(``S`` the displacements, contact forces and the pad's pose; ``P`` the pad's normal load, N).
Backward Euler takes each contact's slip along the chord with the slip direction at the
end of the step: first order in the load step where every contact slips through the
unloading (``benchmarks/release_error_source.py``); the midpoint's slip direction is the
mid-step's: second order where no contact changes state (docs/release.md).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..fem.elasticity import internal_force
from .command import Command, PadLoad
from .held import joined_report, pad_loading
from .measure import SEPARATION_FORCE, measure
from .model import Model, State
from .newton import Equilibrium
from .step import step

__all__ = ["MIDPOINT_LOAD_TOL", "midpoint_load_step"]

MIDPOINT_LOAD_TOL = 1e-6
"""A half step whose pad load missed its target by more than this fraction of the load scale ended past a jump
of the load (the pad let go at once): it is not extrapolated."""


def midpoint_load_step(model: Model, state: State, command: PadLoad, local_problem_hook=None, consume: bool = False,
                       solve=None):
    """A load step from the pad's load ``P_a`` (``state``'s) to ``P_b =
    command.load`` by the implicit midpoint rule: a backward-Euler step to the
    mid load ``P_m = (P_a + P_b) / 2`` (state ``S_m``), then
    the state extrapolated linearly to the end,

        S_b = 2 S_m - S_a      (displacements, contact forces, the pad's pose),

    whose pad load is ``P_b`` and whose resultant is balanced exactly (both are
    linear in ``S``).  Each contact's slip over the step is then twice its slip
    to the mid load, in the direction the mid-step forces give it: the friction
    law at the middle of the step, not at its end: second order in the load
    step where no contact changes state, where backward Euler (the slip
    direction at the end of the step) is first order (docs/release.md).  The extrapolated
    state is not itself a solution (its contact forces meet the law to second
    order in the step); the next step starts from it, and the release's last
    step (to ``P = 0``) is backward Euler, so the rest is a solution.

    Where the half step ended past a jump of the load (``MIDPOINT_LOAD_TOL``), a
    contact opened or closed in it, the extrapolation pulls on a contact (a
    normal force below zero: the midpoint rule does not damp a stiff contact's
    oscillation, measured on a pad 100 x the floor's) or inverts an
    element, the half step stands and a second backward-Euler step goes on to
    ``P_b``: at most two step solves per load step.  ``local_problem_hook`` goes to
    each step (:func:`~fe_contact.stepping.step.step`); ``solve(model, state, command,
    consume=...)`` takes them instead if given (a sequence that records its steps for
    their derivatives, :mod:`~fe_contact.stepping.release_derivatives`).  Returns ``(State, StepReport)``."""
    t0 = time.perf_counter()
    solve = solve or (lambda m, s, c, consume=False: step(m, s, c, local_problem_hook, consume=consume))
    start = float(state.reaction[model.n_lower:, 0].sum())
    middle, first = solve(model, state, replace(command, load=0.5 * (start + command.load)), consume=consume)
    if not first.converged:
        return middle, first
    U = 2.0 * middle.displacement - state.displacement
    r = 2.0 * middle.reaction - state.reaction
    _, min_det = internal_force(model.geometry, model.mesh.elements, U, model.material)
    scale = max(start, model.weight)
    if abs(-float(first.upper_force[2]) - 0.5 * (start + command.load)) > MIDPOINT_LOAD_TOL * scale \
            or np.any(_closed(state.reaction) != _closed(middle.reaction)) or np.any(r[:, 0] < 0) or not min_det > 0:
        end, second = solve(model, middle, command, consume=True)
        if not second.converged:
            return middle, second
        taken = Command(*(end.upper_translation - state.upper_translation), end.upper_rotation - state.upper_rotation)
        return replace(end, step_index=state.step_index + 1), joined_report(
            state, first, second, taken, "converged in two backward-Euler halves (a contact opened or closed)")
    translation = 2.0 * middle.upper_translation - state.upper_translation
    rotation = 2.0 * middle.upper_rotation - state.upper_rotation
    plate = 2.0 * middle.plate - state.plate  # a compliant gripper's plate pose (the commanded one if rigid)
    end = replace(state, displacement=U, reaction=r, upper_translation=translation, upper_rotation=rotation,
                  plate=plate, step_index=state.step_index + 1, tangent=None)
    eq = Equilibrium(first.status, "converged (implicit midpoint: the half step extrapolated)", U, r, None,
                     float(min_det), first.newton_residual, 0.0, first.iterations, first.tangent_updates, None,
                     first.timings)
    taken = Command(*(translation - state.upper_translation), rotation - state.upper_rotation)
    extra = None if model.gripper.rigid else {  # the springs' force k (c - p), linear in the state
        "gripper_force": 2.0 * first.gripper_force - _gripper_force(model, state), "plate": plate}
    report = measure(model, state, taken, eq, t0, pad_loading(model, end), extra)
    return replace(end, slip_path=report.slip_path), report


def _gripper_force(model: Model, state: State) -> np.ndarray:
    """A compliant gripper's spring force ``k (c - p)`` (3,), N, N, N m, at ``state`` (``c`` its commanded pose)."""
    commanded = np.array([*state.upper_translation[:2], state.upper_rotation])
    return np.asarray(model.gripper.stiffness, dtype=float) * (commanded - state.plate)


def _closed(reaction: np.ndarray) -> np.ndarray:
    """Which contacts carry a normal force (above ``SEPARATION_FORCE`` of the largest force component)."""
    return reaction[:, 0] > SEPARATION_FORCE * np.abs(reaction).max()
