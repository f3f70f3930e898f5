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

from dataclasses import replace

import numpy as np

from ..fem.elasticity import internal_force
from .command import Command, PadLoad
from .held import joined_report, pad_loading
from .measure import SEPARATION_FORCE, measure
from .model import Model, State, StepReport
from .newton import Equilibrium
from .pad_load import pad_normal_load

__all__ = ["MIDPOINT_LOAD_TOL", "closed_contacts", "extrapolated", "midpoint_half", "missed_load", "two_halves"]

MIDPOINT_LOAD_TOL = 1e-6
"""A half step whose pad load missed its target by more than this fraction of the load scale ended past a jump
of the load (the pad let go at once): it is not extrapolated."""


def missed_load(model: Model, start: State, report: StepReport, load: float) -> bool:
    """Whether a load step from ``start`` to ``load`` (N) ended past a jump of the
    load (the pad let go at once): the pad's force of ``report`` off ``load`` by more
    than ``MIDPOINT_LOAD_TOL`` of the larger of the start's load and the weight."""
    scale = max(pad_normal_load(model, start), model.weight)
    return abs(-float(report.upper_force[2]) - load) > MIDPOINT_LOAD_TOL * scale


def midpoint_half(model: Model, state: State, command: PadLoad) -> PadLoad:
    """The half step of a load step from the pad's load ``P_a`` (``state``'s) to
    ``P_b = command.load`` by the implicit midpoint rule: the backward-Euler step
    (:func:`~fe_contact.stepping.step.step`) to the mid load ``P_m = (P_a + P_b) / 2``.
    The stepping loop (:class:`~fe_contact.stepping.sequence.StepSequence`) takes it,
    then :func:`extrapolated`, and where that returns None a second backward-Euler
    step from the half step to ``P_b`` (:func:`two_halves`): at most two step solves
    per load step."""
    return replace(command, load=0.5 * (pad_normal_load(model, state) + command.load))


def extrapolated(model: Model, state: State, command: PadLoad, middle: State, first: StepReport, t0: float):
    """The end of the midpoint load step from ``state`` to ``command.load``, its half
    step ``(middle, first)`` (:func:`midpoint_half`, converged) extrapolated linearly,

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

    None where the half step ended past a jump of the load (``MIDPOINT_LOAD_TOL``),
    a contact opened or closed in it, the extrapolation pulls on a contact (a
    normal force below zero: the midpoint rule does not damp a stiff contact's
    oscillation, measured on a pad 100 x the floor's) or inverts an element: the
    half step stands and a second backward-Euler step goes on to ``P_b``
    (:func:`two_halves`).  ``t0`` (s, ``time.perf_counter``) the step's start.
    Returns ``(State, StepReport)`` or None."""
    U = 2.0 * middle.displacement - state.displacement
    r = 2.0 * middle.reaction - state.reaction
    _, min_det = internal_force(model.geometry, model.mesh.elements, U, model.material)
    if missed_load(model, state, first, midpoint_half(model, state, command).load) \
            or np.any(closed_contacts(state.reaction) != closed_contacts(middle.reaction)) or np.any(r[:, 0] < 0) or not min_det > 0:
        return None
    translation = 2.0 * middle.upper_translation - state.upper_translation
    rotation = 2.0 * middle.upper_rotation - state.upper_rotation
    plate = 2.0 * middle.plate - state.plate  # a compliant gripper's plate pose (the commanded one if rigid)
    end = replace(state, displacement=U, reaction=r, upper_translation=translation, upper_rotation=rotation,
                  plate=plate, step_index=state.step_index + 1, tangent=None)
    note = "" if first.message == "converged" else f"; its half step {first.message}"  # e.g. the path tolerance
    eq = Equilibrium(first.status, f"converged (implicit midpoint: the half step extrapolated{note})", U, r, None,
                     float(min_det), first.newton_residual, 0.0, first.iterations, first.tangent_updates, None,
                     first.timings)
    taken = Command(*(translation - state.upper_translation), rotation - state.upper_rotation)
    extra = None if model.gripper.rigid else {  # the springs' force k (c - p), linear in the state
        "gripper_force": 2.0 * first.gripper_force - _gripper_force(model, state), "plate": plate}
    report = measure(model, state, taken, eq, t0, pad_loading(model, end), extra)
    return replace(end, slip_path=report.slip_path), report


def two_halves(state: State, first: StepReport, end: State, second: StepReport):
    """The load step from ``state`` taken as its half step (report ``first``) and a
    second backward-Euler step to ``end`` (report ``second``, converged), where
    :func:`extrapolated` may not extrapolate: ``(State, StepReport)``, the whole
    step's command, both parts' Newton iterations."""
    taken = Command(*(end.upper_translation - state.upper_translation), end.upper_rotation - state.upper_rotation)
    return replace(end, step_index=state.step_index + 1), joined_report(
        state, first, second, taken, "converged in two backward-Euler halves (a contact opened or closed)")


def _gripper_force(model: Model, state: State) -> np.ndarray:
    """A compliant gripper's spring force ``k (c - p)`` (3,), N, N, N m, at ``state`` (``c`` its commanded pose)."""
    commanded = np.array([*state.upper_translation[:2], state.upper_rotation])
    return np.asarray(model.gripper.stiffness, dtype=float) * (commanded - state.plate)


def closed_contacts(reaction: np.ndarray) -> np.ndarray:
    """Which contacts carry a normal force (above ``SEPARATION_FORCE`` of the largest force component)."""
    return reaction[:, 0] > SEPARATION_FORCE * np.abs(reaction).max()
