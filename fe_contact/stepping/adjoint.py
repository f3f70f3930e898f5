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

The compliant gripper's plate balance ``(dF/dp + diag k) dp = k dc + (c - p)
dk - dF/d(input)`` (:mod:`~fe_contact.stepping.derivatives`) is transposed
too: with ``mu`` the weights of ``dp`` (the plate's outputs and what ``dp``
moves, the three plate directions of the held step, solved forward once per
step), ``nu = (dF/dp + diag k)^-T mu`` weighs ``k dc`` (the commands),
``(c - p) dk`` (the stiffnesses) and ``-dF/d(input)`` (through the transposed
plate wrench, :func:`~fe_contact.stepping.sensitivity.plate_wrench_adjoint`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .derivatives import OUTPUTS, PARAMETERS, _check
from .step_derivative import report_outputs
from .model import Model, State, Status, TangentCache, initial_state
from .predictor import commanded_pose
from .sensitivity import (HeldLinearisation, lower_pose_derivative, plate_wrench_adjoint, plate_wrench_derivative,
                          upper_pose_jacobian)
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
        As :func:`~fe_contact.stepping.derivatives.rollout_derivatives`, or
        weights of the wrong shape.
    """
    commands, parameters = _check(model, commands, parameters, pad=False)
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
        steps.append((lin, commanded_pose(state, command)[1]) if model.gripper.rigid
                     else _plate_balance(model, state, command, report, lin))
        state = replace(new_state, tangent=TangentCache(lin.tangent))
        outputs[k] = report_outputs(report, state)
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
        lin = steps[k][0]
        pose_map = lower_pose_derivative(model, lin.U, basis)  # (3, 2 n_lower)
        lam_U = lam_U.copy()
        lam_U[lower_xy] += g[k, :3] @ pose_map
        lam_force = np.tile(g[k, 3:6], (model.held_nodes.size, 1))
        if model.gripper.rigid:
            lam_start, lam_upper, lam_step = lin.solve_adjoint(lam_U, lam_force)
            lam_pose = lam_pose + upper_pose_jacobian(model, steps[k][1]).T @ lam_upper
            lam_pose[[0, 1, 3]] += g[k, 6:9]  # the plate of a rigid drive is the commanded pose
        else:
            lam_start, lam_c, lam_step, lam_params[6:] = _plate_balance_adjoint(model, steps[k], lam_U, lam_force,
                                                                                g[k, 6:9], lam_params[6:])
            lam_pose = lam_pose + lam_c
        lam_params[:6] += lam_step
        d_commands[k] = lam_pose  # d pose_k / d command_j = I for j <= k
        lam_U = lam_start
    return d_commands, lam_params


def _plate_balance(model: Model, state: State, command, report, lin: HeldLinearisation):
    """What the backward pass needs of a compliant-gripper step: the held step's
    response to the three plate directions (displacements, upper-face forces),
    the balance matrix ``A = dF/dp + diag k`` and ``c - p``."""
    translation, rotation = commanded_pose(state, command)
    p = np.array(report.plate)
    Jp = upper_pose_jacobian(model, float(p[2]))
    n = model.mesh.n_dofs
    held = lin.solve(np.zeros((n, 3)), Jp[:, [0, 1, 3]], np.zeros((6, 3)))
    f_upper = lin.f_int[model.upper_dofs].reshape(-1, 3)
    dF = plate_wrench_derivative(model, report.displacement, f_upper, held.displacement, held.upper_force)
    c = np.array([translation[0], translation[1], rotation])
    return lin, Jp, held, np.linalg.inv(dF + np.diag(model.gripper.stiffness)), c - p, f_upper


def _plate_balance_adjoint(model: Model, step, lam_U, lam_force, lam_plate, lam_stiffness):
    """The transpose of a compliant step's derivatives (module docstring):
    weights of the start displacements, of the commanded pose (4,), of the
    held step's parameters (6,) and the gripper's stiffnesses (2,) updated."""
    lin, Jp, held, A_inv, c_p, f_upper = step
    mu = held.displacement.T @ lam_U + np.einsum("nik,ni->k", held.upper_force, lam_force) + lam_plate
    nu = A_inv.T @ mu
    w_U, w_force = plate_wrench_adjoint(model, lin.U, f_upper, nu)
    lam_start, lam_upper, lam_step = lin.solve_adjoint(lam_U - w_U, lam_force - w_force)
    lam_c = np.zeros(4)
    lam_c[2] = Jp[:, 2] @ lam_upper  # the plate's height is commanded
    lam_c[[0, 1, 3]] = model.gripper.stiffness * nu  # k dc
    lam_stiffness = lam_stiffness + np.array([nu[0] * c_p[0] + nu[1] * c_p[1], nu[2] * c_p[2]])
    return lam_start, lam_c, lam_step, lam_stiffness


__all__ = ["RolloutGradient", "rollout_gradient"]
