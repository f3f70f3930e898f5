"""The derivatives of one converged step (:mod:`fe_contact.stepping.derivatives`
sweeps them through a rollout, :mod:`~fe_contact.stepping.release_derivatives`
through a pad's load steps).

A step from ``state`` to ``new_state`` under the commanded pose ``c`` (its
derivative ``dc = d_state.pose + d_command`` (4, J)) is linearised at its
converged configuration by the implicit function theorem: a held upper face by
:class:`~fe_contact.stepping.sensitivity.HeldLinearisation` (a compliant
gripper's plate balance ``(dF/dp + diag k) dp = k dc + (c - p) dk -
dF/d(input)`` by :func:`~fe_contact.stepping.sensitivity.solve_compliant`), a
frictional pad by :class:`~fe_contact.stepping.pad_sensitivity.PadLinearisation`
(:func:`~fe_contact.stepping.pad_sensitivity.solve_compliant_pad`).  It gives
the state's derivative :class:`StateDerivative`, the outputs
:data:`~fe_contact.stepping.derivatives.OUTPUTS` and theirs, and each
contact's branch margins (:func:`~fe_contact.stepping.transitions.margins`).
``seeds`` (8, J) are the derivatives of the parameters ``mu_x, mu_y, angle,
young, poisson, density, stiffness_xy, stiffness_yaw`` along the J inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .model import State, Status, StepReport, TangentCache
from .pad_sensitivity import PadLinearisation, solve_compliant_pad
from .predictor import commanded_pose
from .sensitivity import HeldLinearisation, lower_pose_derivative, solve_compliant, upper_pose_jacobian
from .transitions import margins

__all__ = ["StateDerivative", "report_outputs", "step_derivative"]


@dataclass(frozen=True)
class StateDerivative:
    """Derivative of a state along J inputs: ``displacement`` (n_dofs, J), m;
    the commanded pose ``(t_x, t_y, t_z, theta)`` (4, J); the plate pose (3, J);
    the contact forces ``reaction`` (n_contacts, 3, J), local, N (None where not
    followed: the midpoint's extrapolation fraction reads it,
    :mod:`~fe_contact.stepping.release_derivatives`)."""

    displacement: np.ndarray
    pose: np.ndarray
    plate: np.ndarray
    reaction: np.ndarray | None = None


def step_derivative(model, state, new_state, report, d_state, d_command, seeds):
    """The derivatives of the step from ``state`` that ended in ``(new_state,
    report)``: (state with the tangent at the converged configuration, d_state,
    outputs (9,), d_outputs (9, J), the margins of its contacts
    :func:`~fe_contact.stepping.transitions.margins` with the contacts to skip),
    or (status, message) if the step or its linearisation failed."""
    if not report.converged:
        return report.status, f"step {state.step_index + 1}: {report.message}"
    translation, rotation = commanded_pose(state, report.command)
    d_pose = d_state.pose + d_command
    if model.pad is not None:
        return _pad_step_derivative(model, state, new_state, report, d_state, d_pose, seeds, translation, rotation)
    lin = HeldLinearisation(model, state.displacement, report.displacement, report.reaction_local,
                            report.node_status)
    if lin.failure:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: {lin.failure}"
    J = d_pose.shape[1]
    if model.gripper.rigid:
        d_upper = upper_pose_jacobian(model, rotation) @ d_pose
        held = lin.solve(d_state.displacement, d_upper, seeds[:6])
        d_plate = d_pose[[0, 1, 3]]
    else:
        held, d_plate = solve_compliant(model, report, lin, d_state.displacement, d_pose, seeds,
                                        np.array([translation[0], translation[1], rotation]))
    dU = held.displacement
    d_out = np.vstack([lower_pose_derivative(model, report.displacement, dU), held.upper_force.sum(axis=0), d_plate])
    outputs = report_outputs(report, new_state)
    new_state = replace(new_state, tangent=TangentCache(lin.tangent))  # the next step's start tangent
    return (new_state, StateDerivative(dU, d_pose, d_plate, held.reaction), outputs, d_out.reshape(9, J),
            _margins(model, lin, held, seeds))


def _margins(model, lin, held, seeds):
    """The branch margins of a step's contacts and their derivatives
    (:func:`~fe_contact.stepping.transitions.margins`; ``mu_x``, ``mu_y`` the
    floor's), and no contact skipped."""
    n, n_lower = model.n_contacts, model.n_lower
    dmu = np.zeros((n, 2, seeds.shape[1]))
    dmu[:n_lower] = seeds[:2]
    m, dm, kind = margins(lin.node_status, lin.r, lin.u_local, model.contacts.mu_x, model.contacts.mu_y,
                          held.reaction, held.contact_motion, dmu)
    return m, dm, kind, np.zeros(n, dtype=bool)


def _pad_step_derivative(model, state, new_state, report, d_state, d_pose, seeds, translation, rotation):
    """:func:`step_derivative` of a step with a frictional pad
    (:class:`~fe_contact.stepping.pad_sensitivity.PadLinearisation`; a compliant
    gripper's plate by :func:`~fe_contact.stepping.pad_sensitivity.solve_compliant_pad`)."""
    if "half steps" in report.message:  # split where the whole step failed: the halves' middle is not kept
        return Status.TANGENT_SINGULAR, (f"step {state.step_index + 1} was taken in halves ({report.message}): "
                                         "its derivative through them is not available")
    r = np.vstack([report.reaction_local, report.pad_reaction])
    if model.gripper.rigid:
        lin = PadLinearisation(model, state, report.displacement, r, translation, rotation)
        held = None if lin.failure else lin.solve_pad(d_state.displacement, d_state.pose, d_pose, seeds[:6])
        d_plate = d_pose[[0, 1, 3]]
    else:
        commanded = np.array([*translation, rotation])
        d_start_pose = np.vstack([d_state.plate[:2], d_state.pose[2], d_state.plate[2]])
        d_stiffness = np.vstack([seeds[6], seeds[6], seeds[7]])
        lin, held, d_plate = solve_compliant_pad(model, state, report.displacement, r, commanded,
                                                 np.array(new_state.plate), d_state.displacement, d_start_pose,
                                                 d_pose, seeds[:6], d_stiffness)
    if lin.failure:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: {lin.failure}"
    dU = held.displacement
    d_out = np.vstack([lower_pose_derivative(model, report.displacement, dU), held.upper_force.sum(axis=0), d_plate])
    return (new_state, StateDerivative(dU, d_pose, d_plate, held.reaction), report_outputs(report, new_state), d_out,
            _margins(model, lin, held, seeds))


def report_outputs(report: StepReport, state: State) -> np.ndarray:
    """:data:`~fe_contact.stepping.derivatives.OUTPUTS` of a converged step (9,)
    ending in ``state`` (the plate pose of the state: a rigid drive's report
    carries the start's)."""
    return np.concatenate([report.lower_centroid[:2], [report.lower_yaw], report.upper_force, state.plate])
