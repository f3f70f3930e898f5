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

The extrapolation goes as far as every contact stays on the branch of the contact law it
holds at the mid load (:func:`extrapolation_fraction`: its normal force, gap or friction
cone), ``S_w = S_m + w (S_m - S_a)`` with ``w`` in [0, 1] continuous in the data; where
``w < 1`` a backward-Euler step from ``S_w`` to ``P_b`` ends the load step (at most two step
solves).  The rule before it chose between ``w = 1`` and ``w = 0`` by a threshold on the
contact forces, and the rest pose jumped where a contact sat at it.
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

__all__ = ["CONE_TOL", "MIDPOINT_LOAD_TOL", "closed_contacts", "contact_gaps", "extrapolated", "extrapolation_fraction",
           "fraction_bounds", "midpoint_half", "missed_load", "partial_state", "two_halves"]

CONE_TOL = 1e-6
"""A contact whose force is inside its cone by more than this fraction of its normal force at a load step's start
sticks there (:func:`extrapolation_fraction`); a slipping contact's force is on the cone to the local solver's
tolerance."""

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
    then :func:`extrapolated` where :func:`extrapolation_fraction` is 1, else a second
    backward-Euler step from :func:`partial_state` to ``P_b`` (:func:`two_halves`): at
    most two step solves per load step."""
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

    Only where :func:`extrapolation_fraction` is 1 (the stepping loop asks it
    first); otherwise the step goes on from :func:`partial_state` by a second
    backward-Euler step (:func:`two_halves`).  ``t0`` (s, ``time.perf_counter``)
    the step's start.  Returns ``(State, StepReport)``."""
    end = partial_state(state, middle, 1.0)
    U, r = end.displacement, end.reaction
    _, min_det = internal_force(model.geometry, model.mesh.elements, U, model.material)
    note = "" if first.message == "converged" else f"; its half step {first.message}"  # e.g. the path tolerance
    eq = Equilibrium(first.status, f"converged (implicit midpoint: the half step extrapolated{note})", U, r, None,
                     float(min_det), first.newton_residual, 0.0, first.iterations, first.tangent_updates, None,
                     first.timings)
    taken = Command(*(end.upper_translation - state.upper_translation), end.upper_rotation - state.upper_rotation)
    extra = None if model.gripper.rigid else {  # the springs' force k (c - p), linear in the state
        "gripper_force": 2.0 * first.gripper_force - _gripper_force(model, state), "plate": end.plate}
    report = measure(model, state, taken, eq, t0, pad_loading(model, end), extra)
    return replace(end, slip_path=report.slip_path), report


def partial_state(state: State, middle: State, w: float) -> State:
    """The half step ``S_m`` (``middle``) extrapolated by the fraction ``w`` of a half step,
    ``S_w = S_m + w (S_m - S_a)`` (displacements, contact forces, the pad's pose, a compliant
    gripper's plate): its pad load is ``P_m + w (P_m - P_a)`` (linear).  ``w = 0`` is ``middle``
    itself, ``w = 1`` the whole step's extrapolation :func:`extrapolated`."""
    if w == 0.0:
        return middle

    def ahead(name):
        return (1.0 + w) * getattr(middle, name) - w * getattr(state, name)

    return replace(middle, displacement=ahead("displacement"), reaction=ahead("reaction"),
                   upper_translation=ahead("upper_translation"), upper_rotation=ahead("upper_rotation"),
                   plate=ahead("plate"), slip_path=ahead("slip_path"), tangent=None)


def extrapolation_fraction(model: Model, state: State, middle: State, first: StepReport, load: float) -> float:
    """How far the half step ``S_a -> S_m`` (``state``, ``middle``; ``first`` its report, to the mid
    load ``load``, N) may be extrapolated: the largest ``w`` in [0, 1] for which
    ``S_w = S_m + w (S_m - S_a)`` (:func:`partial_state`) keeps each contact on the branch of the
    contact law it holds at ``S_m`` (:func:`fraction_bounds`), 0 where the half step ended past a
    jump of the load (:func:`missed_load`) or ``S_w`` would invert an element.  ``w = 1`` is the
    midpoint rule (:func:`extrapolated`); below, a backward-Euler step from ``S_w`` ends the step
    (:func:`two_halves`).  Each bound is continuous in the data and tends to 0 as its contact's
    event (opening, closing, leaving the cone) tends to the mid load from above; where the event
    tends to the end of the step, ``w`` tends to 1 (docs/release.md)."""
    if missed_load(model, state, first, load):
        return 0.0
    w = float(np.clip(np.min(fraction_bounds(model, state, middle)[0], initial=1.0), 0.0, 1.0))
    if w > 0.0:
        _, min_det = internal_force(model.geometry, model.mesh.elements, partial_state(state, middle, w).displacement,
                                    model.material)
        if not min_det > 0:
            return 0.0
    return w


def fraction_bounds(model: Model, state: State, middle: State) -> tuple[np.ndarray, np.ndarray]:
    """Each contact's bound on the extrapolation fraction ``w`` (:func:`extrapolation_fraction`)
    and its kind (n_contacts,): the ``w`` at which the linear extrapolation ``x(w) = x_m + w (x_m -
    x_a)`` takes it off the branch it holds at ``S_m`` (inf if never):

    - ``"force"``, closed at ``S_m`` (:func:`closed_contacts`): its normal force reaches 0,
      ``w = r_n,m / (r_n,a - r_n,m)`` where it falls (0 where it was open at ``S_a``: its gap
      would turn negative);
    - ``"gap"``, open at ``S_m``: its gap (:func:`contact_gaps`) reaches 0, ``w = g_m / (g_a -
      g_m)`` where it closes (0 where it was closed at ``S_a``: its force would turn negative);
    - ``"cone"``, inside its elliptic cone at ``S_m`` by more than ``CONE_TOL`` (it sticks): its
      force reaches the cone ``|M^-1 r_t| = r_n`` (the first root ``w > 0`` of a quadratic).

    A contact on its cone at ``S_m`` slips: the second-order overshoot of its extrapolated force is
    the midpoint rule's and no bound."""
    ra, rm = state.reaction, middle.reaction
    n = ra.shape[0]
    bound, kind = np.full(n, np.inf), np.full(n, "", dtype=object)
    closed, was_closed = closed_contacts(rm), closed_contacts(ra)
    falling = closed & (rm[:, 0] < ra[:, 0])
    bound[falling] = rm[falling, 0] / (ra[falling, 0] - rm[falling, 0])
    kind[falling] = "force"
    ga, gm = contact_gaps(model, state), contact_gaps(model, middle)
    closing = ~closed & (gm < ga)
    bound[closing] = np.maximum(gm[closing], 0.0) / (ga[closing] - gm[closing])
    kind[closing] = "gap"
    changed = closed != was_closed  # opened or closed in the half step: its force or gap would change sign
    bound[changed] = 0.0
    kind[changed] = np.where(closed[changed], "gap", "force")
    mu = np.stack([model.contacts.mu_x, model.contacts.mu_y], axis=1)
    inside = closed & (np.linalg.norm(rm[:, 1:] / mu, axis=1) < (1.0 - CONE_TOL) * rm[:, 0])
    cone = np.full(n, np.inf)
    cone[inside] = _cone_exit(ra[inside], rm[inside], mu[inside])
    kind[cone < bound] = "cone"
    return np.minimum(bound, cone), kind


def _cone_exit(ra: np.ndarray, rm: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """For contacts (k,) inside their cone ``|M^-1 r_t| <= r_n`` at ``rm`` (k, 3), the first
    ``w > 0`` at which ``r(w) = rm + w (rm - ra)`` leaves it, inf if never: the smallest positive
    root of ``|M^-1 t(w)|^2 - n(w)^2`` with ``n(w) >= 0``."""
    d = rm - ra
    t0, dt = rm[:, 1:] / mu, d[:, 1:] / mu
    A = (dt * dt).sum(axis=1) - d[:, 0] ** 2
    B = 2.0 * ((t0 * dt).sum(axis=1) - rm[:, 0] * d[:, 0])
    C = (t0 * t0).sum(axis=1) - rm[:, 0] ** 2
    sq = np.sqrt(np.maximum(B * B - 4.0 * A * C, 0.0))
    linear = np.abs(A) <= 1e-14 * (np.abs(B) + np.abs(C))
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.where(linear, np.stack([-C / B, -C / B]), np.stack([(-B - sq) / (2.0 * A), (-B + sq) / (2.0 * A)]))
        valid = np.isfinite(roots) & (roots > 0.0) & (rm[:, 0] + roots * d[:, 0] >= 0.0)
    return np.where(valid, roots, np.inf).min(axis=0)


def contact_gaps(model: Model, state: State) -> np.ndarray:
    """The contacts' gaps (n_contacts,), m, at ``state`` (the pad's at its pose)."""
    nodes = model.contacts.nodes
    x = model.mesh.nodes[nodes] + state.displacement[nodes]
    zero = np.zeros_like(x)
    return model.contacts.kinematics(x, zero, zero, np.asarray(state.upper_translation, float))[0]


def two_halves(state: State, first: StepReport, end: State, second: StepReport, w: float = 0.0):
    """The load step from ``state`` taken as its half step (report ``first``), extrapolated by the
    fraction ``w`` of it (:func:`extrapolation_fraction`, < 1; 0: the half step itself), and a
    second backward-Euler step from there to ``end`` (report ``second``, converged):
    ``(State, StepReport)``, the whole step's command, both parts' Newton iterations."""
    taken = Command(*(end.upper_translation - state.upper_translation), end.upper_rotation - state.upper_rotation)
    how = "two backward-Euler halves" if w == 0.0 else f"the half step extrapolated by {w:.6g} of it, then backward Euler"
    report = joined_report(state, first, second, taken, f"converged in {how} (a contact at an event of its law)")
    return replace(end, step_index=state.step_index + 1), replace(
        report, slip_increment=(1.0 + w) * first.slip_increment + second.slip_increment)


def _gripper_force(model: Model, state: State) -> np.ndarray:
    """A compliant gripper's spring force ``k (c - p)`` (3,), N, N, N m, at ``state`` (``c`` its commanded pose)."""
    commanded = np.array([*state.upper_translation[:2], state.upper_rotation])
    return np.asarray(model.gripper.stiffness, dtype=float) * (commanded - state.plate)


def closed_contacts(reaction: np.ndarray) -> np.ndarray:
    """Which contacts carry a normal force (above ``SEPARATION_FORCE`` of the largest force component)."""
    return reaction[:, 0] > SEPARATION_FORCE * np.abs(reaction).max()
