"""Reverse mode (adjoint) of a rollout's derivatives, for a scalar objective.

For an objective whose gradient with respect to the outputs is ``g`` (n_steps,
9) (:data:`~fe_contact.stepping.derivatives.OUTPUTS` after every step), the
gradient with respect to every command component and parameter is
``g . d outputs / d inputs``.  Forward mode (:func:`rollout_derivatives`)
costs one forward and one backward substitution per input and step, so
``O(K (4 K + P))`` for K steps; the adjoint runs the transposed step maps
(:meth:`~fe_contact.stepping.sensitivity.HeldLinearisation.solve_adjoint`)
backwards through the steps at two solves per step, ``O(K)``, whatever the
number of inputs.  It keeps every step's linearisation (factorised tangent and
flexibility matrix) until the backward pass: memory grows with the steps.
Rigid drive only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .derivatives import OUTPUTS, PARAMETERS, _check, _report_outputs
from .model import Model, State, Status, TangentCache, initial_state
from .predictor import commanded_pose
from .sensitivity import HeldLinearisation, lower_pose_derivative, upper_pose_jacobian
from .step import step


@dataclass(frozen=True)
class RolloutGradient:
    """Gradient of ``sum(weights * outputs)`` over a rollout.

    Attributes
    ----------
    status : Status
    message : str
    outputs : ndarray, shape (n_steps, 9)
    value : float
        ``sum(weights * outputs)``.
    d_commands : ndarray, shape (n_steps, 4)
        With respect to ``(dx, dy, dz, dtheta)`` of each command.
    d_parameters : ndarray, shape (n_parameters,)
    parameters : tuple of str
    """

    status: Status
    message: str
    outputs: np.ndarray
    value: float
    d_commands: np.ndarray
    d_parameters: np.ndarray
    parameters: tuple


def rollout_gradient(model: Model, commands, weights, state: State | None = None,
                     parameters=None) -> RolloutGradient:
    """Reverse-mode gradient of ``sum(weights * outputs)`` (module docstring).

    Parameters
    ----------
    weights : array_like, shape (n_steps, 9)
        ``d objective / d outputs``, in the units of :data:`OUTPUTS`.

    Raises
    ------
    ValueError
        As :func:`~fe_contact.stepping.derivatives.rollout_derivatives`, a
        compliant gripper, or weights of the wrong shape.
    """
    commands, parameters = _check(model, commands, parameters)
    if not model.gripper.rigid:
        raise ValueError("rollout_gradient: the adjoint of the compliant gripper's plate balance is not implemented")
    K = len(commands)
    g = np.asarray(weights, dtype=float)
    if g.shape != (K, len(OUTPUTS)) or not np.all(np.isfinite(g)):
        raise ValueError(f"weights must be finite with shape ({K}, {len(OUTPUTS)}), got {g.shape}")
    state = initial_state(model) if state is None else state
    steps, outputs = [], np.zeros((K, len(OUTPUTS)))
    for k, command in enumerate(commands):
        new_state, report = step(model, state, command)
        lin = None
        if report.converged:
            lin = HeldLinearisation(model, state.displacement, report.displacement, report.reaction_local,
                                    report.node_status)
        if lin is None or lin.failure:
            status = report.status if lin is None else Status.TANGENT_SINGULAR
            message = report.message if lin is None else lin.failure
            return RolloutGradient(status, f"step {k + 1}: {message}", outputs[:k], float("nan"),
                                   np.zeros((K, 4)), np.zeros(len(parameters)), parameters)
        steps.append((lin, commanded_pose(state, command)[1]))
        state = replace(new_state, tangent=TangentCache(lin.tangent))
        outputs[k] = _report_outputs(report, state)
    d_commands, lam_params = _backward(model, steps, g)
    d_parameters = np.array([lam_params[PARAMETERS.index(p)] for p in parameters])
    return RolloutGradient(Status.CONVERGED, "", outputs, float(np.sum(g * outputs)), d_commands, d_parameters,
                           parameters)


def _backward(model: Model, steps, g: np.ndarray):
    """The adjoint sweep: weights of each command (K, 4) and of the step parameters (6,)."""
    K, n_dofs = len(steps), model.mesh.n_dofs
    lower_xy = model.lower_dofs[:, :2].ravel()
    basis = np.zeros((n_dofs, lower_xy.size))
    basis[lower_xy, np.arange(lower_xy.size)] = 1.0
    lam_U, lam_pose = np.zeros(n_dofs), np.zeros(4)
    lam_params, d_commands = np.zeros(len(PARAMETERS)), np.zeros((K, 4))
    for k in range(K - 1, -1, -1):
        lin, rotation = steps[k]
        pose_map = lower_pose_derivative(model, lin.U, basis)  # (3, 2 n_lower)
        lam_U = lam_U.copy()
        lam_U[lower_xy] += g[k, :3] @ pose_map
        lam_force = np.tile(g[k, 3:6], (model.mesh.upper.size, 1))
        lam_start, lam_upper, lam_step = lin.solve_adjoint(lam_U, lam_force)
        lam_pose = lam_pose + upper_pose_jacobian(model, rotation).T @ lam_upper
        lam_pose[[0, 1, 3]] += g[k, 6:9]  # the plate of a rigid drive is the commanded pose
        lam_params[:6] += lam_step
        d_commands[k] = lam_pose  # d pose_k / d command_j = I for j <= k
        lam_U = lam_start
    return d_commands, lam_params


__all__ = ["RolloutGradient", "rollout_gradient"]
