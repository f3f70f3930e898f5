"""Measurements of a load step, read off the last Newton iterate.

Per contact node ``i`` (arrays ordered as ``mesh.lower``), with ``r_i = (r_n,
r_tx, r_ty)`` the local contact force, N, and ``du_i`` the in-plane
displacement increment over the step, m (world x, y):

    pressure     p_i = r_n / A_i                          (A_i tributary area, m^2)
    gap          g_i = Z_i + u_z                          (m)
    dissipation  D = - sum_i r_t,i . (T_t du_i)           (J, >= 0 for a dissipative law)
    equilibrium  |sum_i T^T r_i + f_upper + W - f_reg| / force scale
                 (f_upper the gripper's force on the upper face: the drive's
                 reaction, or a frictional pad's contact forces; W the weight
                 vector, f_reg the total regularising spring force, N)
    strain energy  int (lambda/2 tr(E)^2 + mu E:E) dV     (J)

A node is separated when ``r_n <= SEPARATION_FORCE max |r|`` and slipping when
in contact and ``|du_i| > SLIP_DISPLACEMENT max(block size)``; otherwise it
sticks.  Centroids, the lower face's yaw and the twist are the face
kinematics of :mod:`fe_contact.stepping.pose`.
"""

from __future__ import annotations

import time

import numpy as np

from ..fem.elasticity import stored_energy
from ..fem.loads import NO_LOADING, Loading
from .model import Command, Model, NodeStatus, State, StepReport
from .newton import Equilibrium
from .pose import face_centroid_displacement, planar_yaw, twist_angle

SEPARATION_FORCE = 1e-9
"""Normal force, relative to the largest contact force component, at or below which a node counts as separated."""
SLIP_DISPLACEMENT = 1e-9
"""Tangential increment, relative to the largest block dimension, above which a contact node counts as slipping."""


def node_status(model: Model, r: np.ndarray, slip_inc: np.ndarray) -> np.ndarray:
    """:class:`~fe_contact.stepping.model.NodeStatus` of each contact node (n_lower,)
    int8, from its local force ``r`` (n_lower, 3) and in-plane increment
    ``slip_inc`` (n_lower, 2)."""
    r_scale = float(np.abs(r).max()) if r.size else 0.0
    separated = r[:, 0] <= SEPARATION_FORCE * r_scale
    slipping = ~separated & (
        np.linalg.norm(slip_inc, axis=1) > SLIP_DISPLACEMENT * max(model.mesh.size)
    )
    status = np.where(separated, NodeStatus.SEPARATED, np.where(slipping, NodeStatus.SLIP, NodeStatus.STICK))
    return status.astype(np.int8)


def measure(model: Model, state: State, command: Command, eq: Equilibrium, t0: float,
            loading: Loading = NO_LOADING, extra: dict | None = None) -> StepReport:
    """The :class:`~fe_contact.stepping.model.StepReport` of a step from ``state`` under
    ``command`` that ended in ``eq``; ``t0`` is the ``time.perf_counter()`` at
    its start.  ``loading`` is the step's applied loads; ``extra`` holds report
    fields the caller knows better (``upper_force``, ``gripper_force``, ``plate``)."""
    extra = dict(extra or {})
    mesh, lower, T = model.mesh, model.mesh.lower, model.frame
    U, n_lower = eq.displacement, model.n_lower
    r = eq.reaction[:n_lower]  # the floor's; a frictional pad's follow
    contact_world = r @ T
    slip_inc = U[lower, :2] - state.displacement[lower, :2]
    du_local = slip_inc @ T[1:, :2].T  # (n_lower, 2) in (t_x, t_y)
    upper_c = face_centroid_displacement(U[mesh.upper], model.upper_area)
    lower_c = face_centroid_displacement(U[lower], model.lower_area)
    X_lower = mesh.nodes[lower]
    f_int, pad_force = eq.internal_force, _pad_forces(model, eq)
    upper_force, total_contact, eq_err, spring_f = _balance(model, eq, contact_world, pad_force, loading, extra)
    logs = eq.iterations
    return StepReport(
        status=eq.status,
        message=eq.message or "converged",
        step_index=state.step_index + 1,
        command=command,
        displacement=U,
        reaction_local=r,
        reaction_world=contact_world,
        pressure=r[:, 0] / model.lower_area,
        slip_increment=slip_inc,
        slip=np.linalg.norm(U[lower, :2], axis=1),
        slip_path=state.slip_path + np.linalg.norm(slip_inc, axis=1),
        gap=mesh.nodes[lower, 2] + U[lower, 2],
        node_status=node_status(model, r, slip_inc),
        upper_centroid=upper_c,
        lower_centroid=lower_c,
        lower_yaw=planar_yaw(X_lower, X_lower + U[lower], model.lower_area),
        twist=twist_angle(upper_c, lower_c, max(mesh.size)),
        lag=upper_c[:2] - lower_c[:2],
        normal_force=float(r[:, 0].sum()),
        tangential_force=total_contact[:2],
        upper_force=upper_force,
        equilibrium_error=eq_err,
        dissipation=float(-(r[:, 1:] * du_local).sum()),
        newton_iterations=len(logs),
        contact_iterations=sum(log.contact_iterations for log in logs),
        newton_residual=eq.residual,
        contact_residual=logs[-1].contact_residual if logs else 0.0,
        min_det_f=float(eq.min_det_f),
        wall_time=time.perf_counter() - t0,
        iterations=tuple(logs),
        tangent_updates=eq.tangent_updates,
        timings=eq.timings,
        strain_energy=stored_energy(model.geometry, mesh.elements, U, model.material)
        if np.all(np.isfinite(U)) else float("nan"),
        gripper_force=extra.pop("gripper_force", _drive_wrench(model, U, f_int)),
        plate=extra.pop("plate", np.array(state.plate)),
        weight=model.weight,
        regularisation_force=float(np.linalg.norm(spring_f)),
        pad_reaction=eq.reaction[n_lower:], pad_force=pad_force,
    )


def _pad_forces(model: Model, eq: Equilibrium) -> np.ndarray:
    """(n_held, 3) N, world: the pad's force on each node under it, whose sum is
    :func:`_balance`'s drive or pad force (zeros for a released face)."""
    if model.pad is not None:
        return model.contacts.to_world(eq.reaction)[model.n_lower:]
    if eq.internal_force is None or model.upper_dofs.size == 0:
        return np.zeros((model.held_nodes.size, 3))
    return eq.internal_force[model.upper_dofs].reshape(-1, 3)


def _balance(model: Model, eq: Equilibrium, contact_world: np.ndarray, pad_force: np.ndarray, loading: Loading,
             extra: dict):
    """The gripper's force on the block (3,), N (the sum of ``pad_force``, :func:`_pad_forces`;
    ``extra["upper_force"]`` if given), the floor's total force (3,), N, the relative
    equilibrium error of the module docstring and the regularising springs' force
    (n_dofs,), N.  Sets ``extra["gripper_force"]`` for a frictional pad (its plate
    wrench) unless given."""
    U = eq.displacement
    upper_force = pad_force.sum(axis=0)
    if model.pad is not None:
        extra.setdefault("gripper_force", plate_wrench(model, U, pad_force))
    upper_force = extra.pop("upper_force", upper_force)
    total_contact = contact_world.sum(axis=0)
    force_scale = max(np.linalg.norm(upper_force), np.linalg.norm(total_contact), eq.force_scale)
    balance = total_contact + upper_force
    spring_f = loading.spring_force(U)
    if model.body_force is not None or loading.spring is not None:
        balance = balance - spring_f.reshape(-1, 3).sum(axis=0)
        balance[2] -= model.weight
    eq_err = float(np.linalg.norm(balance) / force_scale) if force_scale > 0 else 0.0
    return upper_force, total_contact, eq_err, spring_f


def _drive_wrench(model: Model, U: np.ndarray, f_eff) -> np.ndarray:
    """In-plane force and moment about the plate's centre (3,), N, N, N m, that
    the upper-face drive applies on the block (zeros for a released face)."""
    if f_eff is None or model.upper_dofs.size == 0:
        return np.zeros(3)
    return plate_wrench(model, U, f_eff[model.upper_dofs].reshape(-1, 3))


def plate_wrench(model: Model, U: np.ndarray, f_upper: np.ndarray) -> np.ndarray:
    """In-plane resultant ``(F_x, F_y, M_z)`` (3,), N, N, N m, of upper-face
    nodal forces ``f_upper`` (n_upper, 3), the moment about the face's current
    centre (the plate's centre), for displacements ``U`` (n_nodes, 3)."""
    x = (model.mesh.nodes + U)[model.held_nodes, :2]
    rel = x - x.mean(axis=0)
    moment = float((rel[:, 0] * f_upper[:, 1] - rel[:, 1] * f_upper[:, 0]).sum())
    return np.array([f_upper[:, 0].sum(), f_upper[:, 1].sum(), moment])
