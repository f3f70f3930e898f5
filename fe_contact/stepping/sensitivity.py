"""Sensitivities of a converged held step by the implicit function theorem.

At the end of a step from displacements ``U_0`` with the upper face held at
the pose ``(t, theta)``, the free dofs ``U_f`` and the contact forces ``r``
(n, 3) local satisfy the equilibrium of the free dofs and the contact law
(paper eq. 42-45, sect. 8):

    R = f_int(U; E, nu)_f - f_ext(rho)_f - C^T T(alpha)^T r = 0,
    law(r, u; mu) = 0,    u = T(alpha) w,   w = (U_c - U_0c)_xy, Z_c + U_cz,

``U_p`` (upper face) given by the pose, ``C`` picking the contact dofs out of
the free ones, ``T`` the world -> local contact frame of orthotropy angle
``alpha``.  Differentiating both with respect to an input (a pose
component, a parameter, the start ``U_0``):

    K_ff dU_f = C^T (T^T dr + dT^T r) - K_fp dU_p - d_p(f_int - f_ext)_f      (1)
    du        = W dr + dq,   dq = T (db_c - dw_0) + dT w                         (2)
    A dr + B du + B_mu dmu = 0   (:func:`fe_contact.contact.law_jacobian.law_jacobian`)  (3)

with ``db = K_ff^-1 (rhs of (1) without T^T dr)``, ``W = T C K_ff^-1 C^T T^T``
the flexibility matrix and ``K`` the consistent tangent (material and
geometric stiffness) at the converged ``U``.  (2) into (3) gives the
condensed system ``(A + B W) dr = -B dq - B_mu dmu`` (3n, 3n): one dense LU
per step; then ``dU_f = db + K_ff^-1 C^T T^T dr``.  The tangent ``K_ff`` is
factorised once per step (:class:`~fe_contact.stepping.tangent.Tangent`, which
also gives ``W``) and every input costs one forward and one backward
substitution (:meth:`~fe_contact.stepping.tangent.Tangent.solve_with_contact`:
the contact dofs are eliminated last).  The
derivative of the upper-face force follows from ``K_pf dU_f + K_pp dU_p +
d_p(f_int - f_ext)_p``.  Parameters enter through ``E``, ``nu`` (the
forces' derivatives in the Lame moduli at fixed ``U``, any law of
:mod:`fe_contact.fem.material` on the hex8 or the F-bar hex8), ``rho`` (the dead load ``rho g V_a``), ``mu_x``, ``mu_y`` (slip
rule) and ``alpha`` (the frame ``T``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..contact.friction import frame_derivative
from ..contact.law_jacobian import law_jacobian
from ..fem.assembly import assemble_vector
from ..fem.finite_strain import (
    AUTO_ELEMENT,
    auto_fbar_weight_slope,
    element_force_moduli_derivatives,
    element_force_weight_derivative,
)
from ..fem.loads import body_force
from .held import held_loading
from .model import Model, NodeStatus
from .tangent import Tangent

STEP_PARAMETERS = ("mu_x", "mu_y", "angle", "young", "poisson", "density")
"""Rows of the parameter directions of a held step, in this order."""


@dataclass(frozen=True)
class HeldDerivative:
    """Derivatives of a held step's solution along J input directions.

    Attributes
    ----------
    displacement : ndarray, shape (n_nodes * 3, J)
        ``dU`` (node-major), m per unit input.
    reaction : ndarray, shape (n_contacts, 3, J)
        ``dr`` local, N per unit input.
    upper_force : ndarray, shape (n_upper, 3, J)
        Derivative of the nodal forces ``(f_int - f_ext)`` of the upper face, N per unit input.
    contact_motion : ndarray, shape (n_contacts, 3, J), or None
        ``du`` local: the derivative of each contact's gap and tangential
        increment, m per unit input (for :mod:`~fe_contact.stepping.transitions`).
    """

    displacement: np.ndarray
    reaction: np.ndarray
    upper_force: np.ndarray
    contact_motion: np.ndarray | None = None


class HeldLinearisation:
    """The linearised equations (1)-(3) of the module docstring at a converged held step.

    Parameters
    ----------
    model : Model
        With the upper face held.
    start : ndarray, shape (n_nodes, 3)
        Displacements at the start of the step ``U_0``, m.
    U : ndarray, shape (n_nodes, 3)
        Converged displacements, m.
    r : ndarray, shape (n_contacts, 3)
        Converged local contact forces, N.
    node_status : ndarray, shape (n_contacts,)
        :class:`~fe_contact.stepping.model.NodeStatus` of each contact (the
        branch of the law; see :mod:`fe_contact.contact.law_jacobian`).

    Attributes
    ----------
    tangent : Tangent
        The factorised tangent at ``U`` (a step from this configuration can reuse it).
    failure : str
        Why the linearisation broke down ("" if it did not); then nothing else is set.
    """

    def __init__(self, model: Model, start: np.ndarray, U: np.ndarray, r: np.ndarray, node_status: np.ndarray):
        self.model, self.U, self.r, self.node_status = model, U, r, node_status
        self.failure = ""
        f_int, K, _ = held_loading(model).tangent(model, U)
        self.f_int = f_int
        self.K_fp = K[model.free_dofs][:, model.upper_dofs]
        self.K_p = K[model.upper_dofs]
        try:
            self.tangent = Tangent(model, K)
        except RuntimeError as exc:  # SuperLU: exactly singular
            self.failure = f"tangent stiffness singular at the converged step: {exc}"
            return
        lower, T = model.mesh.lower, model.frame
        self.w = U[lower] - start[lower]
        self.w[:, 2] = model.mesh.nodes[lower, 2] + U[lower, 2]
        u_t = self.w[:, :2] @ T[1:, :2].T
        self.u_local = self.w @ T.T  # the gap and the tangential increments, local
        A, B, self.B_mu = law_jacobian(node_status == NodeStatus.SEPARATED, node_status == NodeStatus.SLIP, r,
                                       u_t, model.friction.mu_x, model.friction.mu_y)
        n = model.n_contacts
        W = self.tangent.W_scaled * self.tangent.w_mean
        M = np.einsum("cij,cjm->cim", B, W.reshape(n, 3, 3 * n)).reshape(3 * n, 3 * n)
        blocks = M.reshape(n, 3, n, 3)
        blocks[np.arange(n), :, np.arange(n), :] += A
        self.B = B
        lu = sla.lu_factor(M, check_finite=False)
        if not np.all(np.isfinite(lu[0])) or np.any(np.diag(lu[0]) == 0.0):
            self.failure = "linearised contact law singular at the converged step"
            return
        self.lu = lu

    def solve(self, d_start: np.ndarray, d_upper: np.ndarray, d_params: np.ndarray) -> HeldDerivative:
        """Derivatives along J input directions.

        Parameters
        ----------
        d_start : ndarray, shape (n_nodes * 3, J)
            ``dU_0``, derivative of the start displacements.
        d_upper : ndarray, shape (n_upper * 3, J)
            ``dU_p``, derivative of the prescribed upper-face displacements.
        d_params : ndarray, shape (6, J)
            Derivatives of the parameters :data:`STEP_PARAMETERS` (``alpha`` in rad).
        """
        model, r = self.model, self.r
        n, J = model.n_contacts, d_start.shape[1]
        T, dT = model.frame, frame_derivative(model.friction.angle)
        d_mu, d_alpha = d_params[:2], d_params[2]
        f_p = self.parameter_force(d_params)  # (n_dofs, J)
        rhs = np.zeros((model.mesh.n_dofs, J))
        rhs[model.lower_dofs.ravel()] = np.outer((r @ dT).ravel(), d_alpha)
        rhs = rhs[model.free_dofs] - self.K_fp @ d_upper - f_p[model.free_dofs]
        db_contact, finish = self.tangent.solve_with_contact(rhs)
        dw = db_contact - d_start[model.lower_dofs.ravel()].reshape(n, 3, J)
        dw[:, 2] += d_start[model.lower_dofs[:, 2]]  # the gap is total, not an increment
        dq = np.einsum("ij,cjk->cik", T, dw) + np.einsum("ij,cj,k->cik", dT, self.w, d_alpha)
        b = -np.einsum("cij,cjk->cik", self.B, dq) - np.einsum("cij,jk->cik", self.B_mu, d_mu)
        dr = sla.lu_solve(self.lu, b.reshape(3 * n, J), check_finite=False).reshape(n, 3, J)
        dU = np.zeros((model.mesh.n_dofs, J))
        dU[model.free_dofs] = finish(np.einsum("ji,cjk->cik", T, dr))
        dU[model.upper_dofs] = d_upper
        d_force = (self.K_p @ dU + f_p[model.upper_dofs]).reshape(-1, 3, J)
        dw = dU[model.lower_dofs.ravel()].reshape(n, 3, J) - d_start[model.lower_dofs.ravel()].reshape(n, 3, J)
        dw[:, 2] += d_start[model.lower_dofs[:, 2]]  # the gap is total
        du = np.einsum("ij,cjk->cik", T, dw) + np.einsum("ij,cj,k->cik", dT, self.w, d_alpha)
        return HeldDerivative(dU, dr, d_force, du)

    def solve_adjoint(self, lam_U: np.ndarray, lam_force: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The transpose of :meth:`solve` (reverse mode): for the weights
        ``lam_U`` (n_dofs,) of ``dU`` and ``lam_force`` (n_upper, 3) of the upper
        face's force derivative, the weights of ``d_start`` (n_dofs,), ``d_upper``
        (n_upper * 3,) and ``d_params`` (6,).  Two solves with the step's factor
        (``K_ff`` is symmetric) and one with the transposed condensed law.
        """
        model, r, n = self.model, self.r, self.model.n_contacts
        T, dT = model.frame, frame_derivative(model.friction.angle)
        lam_U = lam_U + self.K_p.T @ lam_force.ravel()  # dF = K_p dU + f_p
        lam_params = self.parameter_force_adjoint(lam_force.ravel(), model.upper_dofs)
        lam_free = lam_U[model.free_dofs]
        # dU_f = db + K^-1 C^T T^T dr
        x = self.tangent.solve(lam_free)
        lam_dr = (x[self.tangent.contact_index].reshape(n, 3)) @ T.T
        lam_b = sla.lu_solve(self.lu, lam_dr.ravel(), trans=1, check_finite=False).reshape(n, 3)
        lam_dq = -np.einsum("cij,ci->cj", self.B, lam_b)  # b = -B dq - B_mu dmu
        lam_params[:2] -= np.einsum("cij,ci->j", self.B_mu, lam_b)
        lam_dw = lam_dq @ T  # dq = T dw + dT w dalpha
        lam_params[2] += float(np.sum(lam_dq * (self.w @ dT.T)))
        lam_db = lam_free.copy()
        lam_db[self.tangent.contact_index] += lam_dw.ravel()  # dw = C db - dU0 (x, y)
        lam_start = np.zeros(model.mesh.n_dofs)
        lam_start[model.lower_dofs[:, :2].ravel()] = -lam_dw[:, :2].ravel()
        lam_rhs = self.tangent.solve(lam_db)  # db = K^-1 rhs
        lam_upper = lam_U[model.upper_dofs] - self.K_fp.T @ lam_rhs
        full = np.zeros(model.mesh.n_dofs)
        full[model.free_dofs] = lam_rhs
        lam_params[2] += float(np.sum(full[model.lower_dofs.ravel()] * (r @ dT).ravel()))
        lam_params -= self.parameter_force_adjoint(lam_rhs, model.free_dofs)
        return lam_start, lam_upper, lam_params

    def parameter_force_adjoint(self, lam: np.ndarray, dofs: np.ndarray) -> np.ndarray:
        """``lam . d_p (f_int - f_ext)[dofs]`` for each of :data:`STEP_PARAMETERS` (6,)."""
        out = np.zeros(6)
        for i in (3, 4, 5):
            e = np.zeros((6, 1))
            e[i] = 1.0
            out[i] = float(lam @ self.parameter_force(e)[dofs, 0])
        return out

    def parameter_force(self, d_params: np.ndarray) -> np.ndarray:
        """``d_p (f_int - f_ext)`` at fixed ``U`` (n_dofs, J), N per unit input.

        The material's by :meth:`_material_forces`; the dead load is ``rho g V_a``.
        """
        model = self.model
        out = np.zeros((model.mesh.n_dofs, d_params.shape[1]))
        d_young, d_poisson, d_density = d_params[3], d_params[4], d_params[5]
        if np.any(d_young) or np.any(d_poisson):
            f_young, f_poisson = self._material_forces()
            out += np.outer(f_young, d_young) + np.outer(f_poisson, d_poisson)
        if np.any(d_density):
            out -= np.outer(body_force(model.nodal_volume, 1.0), d_density)
        return out


    def _material_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """``d f_int / dE`` and ``d f_int / dnu`` at ``U`` (n_dofs,), N/Pa and N (computed once):
        the forces' derivatives in the Lame moduli at fixed ``U`` (any law, either element,
        :func:`~fe_contact.fem.finite_strain.element_force_moduli_derivatives`) by the chain rule,
        ``lambda = E nu / ((1 + nu)(1 - 2 nu))``, ``mu = E / (2 (1 + nu))``, and for
        ``element="auto"`` between hex8 and F-bar the weight's ``dw/dnu df/dw``
        (:func:`~fe_contact.fem.finite_strain.element_force_weight_derivative`)."""
        if getattr(self, "_material", None) is not None:
            return self._material
        model, mat = self.model, self.model.material
        elements = model.mesh.elements
        d = element_force_moduli_derivatives(model.geometry.grad, model.geometry.dvol, self.U[elements], mat.model,
                                             mat.lame_lambda, mat.lame_mu, model.geometry.fbar_weight)
        f_lam, f_mu = (assemble_vector(elements, x, model.mesh.n_nodes) for x in d)
        E, nu = mat.young, mat.poisson
        dlam_dnu = E * (1.0 + 2.0 * nu**2) / ((1.0 + nu) ** 2 * (1.0 - 2.0 * nu) ** 2)
        dmu_dnu = -E / (2.0 * (1.0 + nu) ** 2)
        f_nu = dlam_dnu * f_lam + dmu_dnu * f_mu
        if model.geometry.element == AUTO_ELEMENT:  # element="auto"'s weight moves with nu
            d_w = element_force_weight_derivative(model.geometry.grad, model.geometry.dvol, self.U[elements],
                                                  mat.model, mat.lame_lambda, mat.lame_mu, model.geometry.fbar_weight)
            f_nu = f_nu + auto_fbar_weight_slope(nu) * assemble_vector(elements, d_w, model.mesh.n_nodes)
        self._material = (mat.lame_lambda * f_lam + mat.lame_mu * f_mu) / E, f_nu
        return self._material


def upper_pose_jacobian(model: Model, rotation: float) -> np.ndarray:
    """Derivative of the upper face's displacements with respect to its pose
    ``(t_x, t_y, t_z, theta)`` (:func:`~fe_contact.stepping.predictor.upper_face_displacement`),
    shape (n_upper * 3, 4): m/m and m/rad."""
    rel = model.mesh.nodes[model.held_nodes] - model.upper_centre
    n_up = rel.shape[0]
    c, s = math.cos(rotation), math.sin(rotation)
    out = np.zeros((n_up, 3, 4))
    out[:, 0, 0] = out[:, 1, 1] = out[:, 2, 2] = 1.0
    out[:, 0, 3] = -s * rel[:, 0] - c * rel[:, 1]
    out[:, 1, 3] = c * rel[:, 0] - s * rel[:, 1]
    return out.reshape(3 * n_up, 4)


def plate_wrench_derivative(model: Model, U: np.ndarray, f_upper: np.ndarray, dU: np.ndarray,
                            df_upper: np.ndarray) -> np.ndarray:
    """Derivative (3, J) of :func:`~fe_contact.stepping.measure.plate_wrench`
    ``(F_x, F_y, M_z)`` for displacement derivatives ``dU`` (n_dofs, J) and
    upper-face force derivatives ``df_upper`` (n_upper, 3, J)."""
    upper = model.held_nodes
    x = (model.mesh.nodes + U)[upper, :2]
    rel = x - x.mean(axis=0)
    d_x = dU.reshape(-1, 3, dU.shape[1])[upper, :2]
    d_rel = d_x - d_x.mean(axis=0)
    f = f_upper
    d_moment = (np.einsum("n,nk->k", rel[:, 0], df_upper[:, 1]) - np.einsum("n,nk->k", rel[:, 1], df_upper[:, 0])
                + np.einsum("nk,n->k", d_rel[:, 0], f[:, 1]) - np.einsum("nk,n->k", d_rel[:, 1], f[:, 0]))
    return np.vstack([df_upper[:, 0].sum(axis=0), df_upper[:, 1].sum(axis=0), d_moment])


def plate_wrench_adjoint(model: Model, U: np.ndarray, f_upper: np.ndarray, weights: np.ndarray):
    """The transpose of :func:`plate_wrench_derivative`: for the weights (3,) of
    ``(dF_x, dF_y, dM_z)``, the weights of ``dU`` (n_dofs,) and of ``df_upper``
    (n_upper, 3).  ``M_z = sum (x - x_bar) f_y - (y - y_bar) f_x`` over the upper face."""
    upper = model.held_nodes
    x = (model.mesh.nodes + U)[upper, :2]
    rel = x - x.mean(axis=0)
    f = f_upper - f_upper.mean(axis=0)  # sum d_rel f = sum d_x (f - f_bar)
    w_force = np.zeros((upper.size, 3))
    w_force[:, 0] = weights[0] - weights[2] * rel[:, 1]
    w_force[:, 1] = weights[1] + weights[2] * rel[:, 0]
    w_U = np.zeros((model.mesh.n_nodes, 3))
    w_U[upper, 0] = weights[2] * f[:, 1]
    w_U[upper, 1] = -weights[2] * f[:, 0]
    return w_U.ravel(), w_force


def lower_pose_derivative(model: Model, U: np.ndarray, dU: np.ndarray) -> np.ndarray:
    """Derivative (3, J) of the lower face's pose ``(x, y, yaw)``: the
    area-weighted centroid displacement and the best-fit yaw
    ``atan2(sum w p x (x), sum w p . x)`` of :func:`~fe_contact.stepping.pose.planar_yaw`,
    for displacement derivatives ``dU`` (n_dofs, J)."""
    lower, w = model.mesh.lower, model.lower_area
    d = dU.reshape(-1, 3, dU.shape[1])[lower, :2]  # (n, 2, J)
    d_centroid = np.einsum("n,nik->ik", w, d) / w.sum()
    X = model.mesh.nodes[lower, :2]
    p = X - (w[:, None] * X).sum(axis=0) / w.sum()
    x = X + U[lower, :2]
    x = x - (w[:, None] * x).sum(axis=0) / w.sum()
    cross = (w * (p[:, 0] * x[:, 1] - p[:, 1] * x[:, 0])).sum()
    dot = (w * (p * x).sum(axis=1)).sum()
    d_cross = np.einsum("n,nk->k", w * p[:, 0], d[:, 1]) - np.einsum("n,nk->k", w * p[:, 1], d[:, 0])
    d_dot = np.einsum("n,nk->k", w * p[:, 0], d[:, 0]) + np.einsum("n,nk->k", w * p[:, 1], d[:, 1])
    d_yaw = (dot * d_cross - cross * d_dot) / (dot**2 + cross**2)
    return np.vstack([d_centroid, d_yaw])

def solve_compliant(model: Model, report, lin: HeldLinearisation, d_start: np.ndarray, d_pose: np.ndarray,
                    seeds: np.ndarray, c: np.ndarray) -> tuple[HeldDerivative, np.ndarray]:
    """Derivatives of a compliant-gripper step (:mod:`fe_contact.stepping.gripper`):
    the plate balance ``g(p) = F(p) - k (c - p) = 0`` differentiated,

        (dF/dp + diag k) dp = k dc + (c - p) dk - dF/d(input)|_p,

    with ``dF/dp`` from three more directions of the same held step.  ``d_start``
    (n_dofs, J), ``d_pose`` (4, J) the commanded pose's, ``seeds`` (8, J) the
    parameters' (the last two the stiffnesses), ``c`` (3,) the commanded plate pose.
    Returns the held step's derivative with ``dp`` eliminated, and ``dp`` (3, J)."""
    J = d_pose.shape[1]
    p = np.array(report.plate)
    Jp = upper_pose_jacobian(model, float(p[2]))  # (3 n_up, 4)
    zeros = np.zeros
    d_upper = np.hstack([np.outer(Jp[:, 2], d_pose[2]), Jp[:, [0, 1, 3]]])
    d_start = np.hstack([d_start, zeros((model.mesh.n_dofs, 3))])
    held = lin.solve(d_start, d_upper, np.hstack([seeds[:6], zeros((6, 3))]))
    f_upper = lin.f_int[model.upper_dofs].reshape(-1, 3)
    dF = plate_wrench_derivative(model, report.displacement, f_upper, held.displacement, held.upper_force)
    k = model.gripper.stiffness
    dk = np.vstack([seeds[6], seeds[6], seeds[7]])
    dc = d_pose[[0, 1, 3]]
    dp = np.linalg.solve(dF[:, J:] + np.diag(k), k[:, None] * dc + (c - p)[:, None] * dk - dF[:, :J])

    def combined(x):
        return x[..., :J] + x[..., J:] @ dp

    return HeldDerivative(*(combined(x) for x in (held.displacement, held.reaction, held.upper_force,
                                                 held.contact_motion))), dp

