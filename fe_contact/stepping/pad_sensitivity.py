"""Sensitivities of a converged step with a frictional pad on the upper face
(``Model(pad=...)``), by the implicit function theorem.

With a frictional pad every dof is free: the block is held by two frictional
planes, the floor's contacts (in the floor's orthotropy frame) and the pad's
(in the pad's frame, normal ``-e_z``), stacked in one
:class:`~fe_contact.contact.bodies.ContactSet`.  At a converged step from
``U_0`` with the pad at pose ``(t, theta)`` (from ``(t_0, theta_0)`` at the
start),

    R = f_int(U; E, nu) - f_ext(rho) - G^T r = 0,     law(r, u; mu) = 0,

``G^T r`` the contact forces ``T_c^T r_c`` on the contact nodes, and the
local kinematics of :meth:`~fe_contact.contact.bodies.ContactSet.kinematics`:

    u_c = (n_c . (x_c - p_c - s), T_t,c (U_c - U_0c - m_c)),

``s = t`` the pad's shift (zero for the floor), ``m_c`` the pad's motion at
the node over the step (:func:`~fe_contact.stepping.held.pad_motion`: the
rigid motion of the pad from ``(t_0, theta_0)`` to ``(t, theta)`` of the
point ``X + U_0``; zero for the floor).  The pad's proximal springs exert no
force at convergence (``Loading.proximal``) and its tension-only geometric
stiffness is a device of the Newton loop: the converged step solves the
equations above, so they are differentiated with the consistent tangent
``K`` and no spring.  ``K`` alone is singular in the free block's rigid
modes; the contacts fix them, so the whole linear system

    [ K        -G^T ] [dU]   [ dG^T r - d_p(f_int - f_ext)           ]
    [ B T S     A   ] [dr] = [ -B (e(dU_0, dt, dt_0, dtheta)) - B_mu dmu ]

is solved at once (one sparse LU per step; ``S`` picks the contact dofs,
``A``, ``B``, ``B_mu`` of :func:`~fe_contact.contact.law_jacobian.law_jacobian`
on each contact's branch, each body with its own friction; ``mu_x``,
``mu_y``, ``angle`` are the floor's).  ``e`` collects what moves the contact
kinematics besides ``dU``: ``-dU_0 - dm`` in the tangential rows, ``-n . ds``
in the normal row, and the floor's frame derivative ``dT w dalpha``.  The pad's
motion differentiates as

    dm_xy = (R - I)(dU_0 - dt_0)_xy + R' rel (dtheta - dtheta_0) + (dt - dt_0)_xy,   dm_z = dt_z - dt_0z,

``R`` the rotation by ``theta - theta_0``, ``R'`` its derivative, ``rel =
X + U_0 - c - t_0`` (``c`` the face's reference centre).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..contact.friction import frame_derivative
from ..contact.law_jacobian import law_jacobian
from .held import held_loading, pad_motion
from .measure import node_status
from .model import Model, NodeStatus, State
from .sensitivity import HeldDerivative, HeldLinearisation

__all__ = ["PadLinearisation", "solve_compliant_pad"]


class PadLinearisation(HeldLinearisation):
    """The linearised equations of the module docstring at a converged step with a frictional pad.

    Parameters
    ----------
    model : Model
        With ``pad`` set.
    state : State
        The step's start.
    U : ndarray, shape (n_nodes, 3)
        Converged displacements, m.
    r : ndarray, shape (n_contacts, 3)
        Converged local forces of every contact (the floor's, then the pad's), N.
    translation, rotation : ndarray (3,), float
        The pad's pose at the end of the step, m and rad.

    Attributes
    ----------
    failure : str
        Why the linearisation broke down ("" if it did not).
    """

    def __init__(self, model: Model, state: State, U: np.ndarray, r: np.ndarray, translation: np.ndarray,
                 rotation: float):
        self.model, self.state, self.U, self.r = model, state, U, r
        self.failure, self.rotation = "", rotation
        contacts, n_lower = model.contacts, model.n_lower
        f_int, K, _ = held_loading(model).tangent(model, U)
        self.f_int, self.K_p = f_int, None
        nodes = contacts.nodes
        gap, slip = contacts.kinematics(model.mesh.nodes[nodes] + U[nodes], U[nodes] - state.displacement[nodes],
                                        pad_motion(model, state, translation, rotation), translation)
        self.slip = slip  # world, for the floor frame's derivative
        self.w = contacts.to_local(slip)
        self.w[:, 0] = gap
        self.u_local = self.w
        # the floor's as the step reports them; the pad's against every contact's force (an open pad's
        # contacts carry rounding only: separated).  A contact slips where its increment is resolved
        # (above SLIP_DISPLACEMENT of the block's size), on the cone's edge or not: below it the
        # increment is the solve's noise (a settle step after the pad opened drifts by 1.3e-14 of the size
        # at newton_tol 1e-10), whose direction the slip rule would differentiate
        status = np.concatenate([node_status(model, r[:n_lower], slip[:n_lower, :2]),
                                 node_status(model, r, slip[:, :2])[n_lower:]])
        floor = np.arange(nodes.size) < n_lower
        self.A, self.B, B_mu = law_jacobian(status == NodeStatus.SEPARATED, status == NodeStatus.SLIP, r,
                                            self.w[:, 1:], contacts.mu_x, contacts.mu_y)
        self.B_mu = B_mu * floor[:, None, None]  # mu_x, mu_y are the floor's
        self.node_status = status
        self.lu = self._factor(K)

    def _factor(self, K):
        """Sparse LU of the whole system (module docstring), or None (``failure`` set)."""
        model, contacts = self.model, self.model.contacts
        n_dofs, n = model.mesh.n_dofs, model.n_contacts
        dofs = model.contact_dofs  # (n, 3) world dofs of each contact
        frames = contacts.frames
        rows_g = np.broadcast_to(dofs[:, None, :], (n, 3, 3)).ravel()  # G^T[dof i of c, (c, j)] = T_c[j, i]
        cols_g = n_dofs + np.broadcast_to((3 * np.arange(n))[:, None, None] + np.arange(3)[None, :, None],
                                          (n, 3, 3)).ravel()
        BT = np.einsum("cab,cbi->cai", self.B, frames)
        rows_b = n_dofs + np.broadcast_to((3 * np.arange(n))[:, None, None] + np.arange(3)[None, :, None],
                                          (n, 3, 3)).ravel()
        cols_b = np.broadcast_to(dofs[:, None, :], (n, 3, 3)).ravel()
        rows_a = n_dofs + (3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None]) + 0 * np.arange(3)
        cols_a = n_dofs + (3 * np.arange(n)[:, None, None] + np.arange(3)[None, None, :]) + 0 * np.arange(3)[:, None]
        Kc = sp.coo_matrix(K)
        M = sp.coo_matrix((np.concatenate([Kc.data, -frames.ravel(), BT.ravel(), self.A.ravel()]),
                           (np.concatenate([Kc.row, rows_g, rows_b, rows_a.ravel()]),
                            np.concatenate([Kc.col, cols_g, cols_b, cols_a.ravel()]))),
                          shape=(n_dofs + 3 * n, n_dofs + 3 * n)).tocsc()
        try:
            return spla.splu(M)
        except RuntimeError as exc:  # exactly singular
            self.failure = f"linearised step with a frictional pad singular: {exc}"
            return None

    def solve_pad(self, d_start: np.ndarray, d_pose_start: np.ndarray, d_pose: np.ndarray,
                  d_params: np.ndarray) -> HeldDerivative:
        """Derivatives along J input directions: ``d_start`` (n_dofs, J) of the
        start displacements, ``d_pose_start``, ``d_pose`` (4, J) of the pad's pose
        ``(t_x, t_y, t_z, theta)`` at the start and the end of the step,
        ``d_params`` (6, J) of :data:`~fe_contact.stepping.sensitivity.STEP_PARAMETERS`.
        ``upper_force`` is the pad's force on each upper-face node (n_upper, 3, J), world."""
        model, r, n_lower = self.model, self.r, self.model.n_lower
        n_dofs, n, J = model.mesh.n_dofs, model.n_contacts, d_start.shape[1]
        dT, d_alpha = frame_derivative(model.friction.angle), d_params[2]
        rhs1 = -self.parameter_force(d_params)
        rhs1[model.lower_dofs.ravel()] += np.outer((r[:n_lower] @ dT).ravel(), d_alpha)
        e = self._kinematics_derivative(d_start, d_pose_start, d_pose)  # world (n, 3, J); normal row apart
        e_local = np.einsum("cij,cjk->cik", model.contacts.frames, e[0])
        e_local[:, 0] = e[1]
        e_local[:n_lower] += np.einsum("ij,cj,k->cik", dT, self.slip[:n_lower], d_alpha)  # d(T w) = dT w
        rhs2 = -np.einsum("cij,cjk->cik", self.B, e_local) - np.einsum("cij,jk->cik", self.B_mu, d_params[:2])
        x = self.lu.solve(np.vstack([rhs1, rhs2.reshape(3 * n, J)]))
        dU, dr = x[:n_dofs], x[n_dofs:].reshape(n, 3, J)
        d_force = np.einsum("cji,cjk->cik", model.contacts.frames[n_lower:], dr[n_lower:])
        du = np.einsum("cij,cjk->cik", model.contacts.frames, dU.reshape(-1, 3, J)[model.contacts.nodes]) + e_local
        return HeldDerivative(dU, dr, d_force, du)

    def _kinematics_derivative(self, d_start, d_pose_start, d_pose):
        """What moves the contacts' kinematics besides ``dU``: the world
        tangential part ``-dU_0 - dm`` (n, 3, J) and the normal one ``-n . ds`` (n, J)."""
        model, state = self.model, self.state
        nodes, n_lower = model.contacts.nodes, model.n_lower
        J = d_start.shape[1]
        d_u0 = d_start.reshape(-1, 3, J)[nodes]
        tangential = -d_u0
        upper = nodes[n_lower:]
        rel = (model.mesh.nodes[upper] + state.displacement[upper] - model.upper_centre
               - state.upper_translation)[:, :2]
        turn = self.rotation - state.upper_rotation
        c, s = math.cos(turn), math.sin(turn)
        R, dR = np.array([[c, -s], [s, c]]), np.array([[-s, -c], [c, -s]])
        dt, dt0 = d_pose[:3], d_pose_start[:3]
        dm = np.zeros((upper.size, 3, J))
        dm[:, :2] = (np.einsum("ij,njk->nik", R - np.eye(2), d_u0[n_lower:, :2] - dt0[None, :2])
                     + np.einsum("ij,nj,k->nik", dR, rel, d_pose[3] - d_pose_start[3]) + (dt - dt0)[None, :2])
        dm[:, 2] = (dt[2] - dt0[2])[None, :]
        tangential[n_lower:] -= dm
        normal = np.zeros((nodes.size, J))
        normal[n_lower:] = -np.einsum("ci,ik->ck", model.contacts.frames[n_lower:, 0, :], dt)
        return tangential, normal

    def plate_force_derivative(self, held: HeldDerivative, d_start: np.ndarray, d_plate_start: np.ndarray,
                                d_turn_end: np.ndarray) -> np.ndarray:
        """Derivative (3, J') of the pad's generalised force on the block ``F = sum_c
        D_c^T f_c`` (:func:`solve_compliant_pad`): ``sum D^T df + sum dD^T f``, the
        moment's arm ``R' rel`` moving with the turn (``R'' = -R``) and with ``rel
        = X + U_0 - c - p_0``.  ``held`` along J' >= J directions (the first J
        those of ``d_start``, ``d_plate_start`` (4, J)); ``d_turn_end`` (J',) of
        the plate's end angle."""
        model, n_lower = self.model, self.model.n_lower
        upper = model.contacts.nodes[n_lower:]
        Jx, J = held.upper_force.shape[2], d_start.shape[1]
        f = model.contacts.to_world(self.r)[n_lower:, :2]  # (n_pad, 2)
        df = held.upper_force[:, :2]  # (n_pad, 2, J')
        rel = (model.mesh.nodes[upper] + self.state.displacement[upper])[:, :2] - model.upper_centre[:2] \
            - self.state.upper_translation[:2]
        turn = self.rotation - self.state.upper_rotation
        c, s = math.cos(turn), math.sin(turn)
        R, dR = np.array([[c, -s], [s, c]]), np.array([[-s, -c], [c, -s]])
        d_rel = np.zeros((upper.size, 2, Jx))
        d_rel[:, :, :J] = d_start.reshape(-1, 3, J)[upper, :2] - d_plate_start[None, :2]
        d_turn = np.array(d_turn_end, dtype=float)
        d_turn[:J] -= d_plate_start[3]
        arm, d_arm = rel @ dR.T, np.einsum("ij,nj,k->nik", -R, rel, d_turn) + np.einsum("ij,njk->nik", dR, d_rel)
        moment = np.einsum("ni,nik->k", arm, df) + np.einsum("nik,ni->k", d_arm, f)
        return np.vstack([df[:, 0].sum(axis=0), df[:, 1].sum(axis=0), moment])


def solve_compliant_pad(model: Model, state: State, U: np.ndarray, r: np.ndarray, commanded: np.ndarray,
                        plate: np.ndarray, d_start: np.ndarray, d_plate_start: np.ndarray, d_commanded: np.ndarray,
                        d_params: np.ndarray, d_stiffness: np.ndarray):
    """Derivatives of a converged step of a compliant gripper with a frictional
    pad (:mod:`fe_contact.stepping.pad_load`: the plate's in-plane pose ``p``
    solved in the step's Newton loop).  The pad is at ``(p_x, p_y, h)``,
    turned by ``p_theta``, from the state's plate pose; the plate balance

        g(p) = F(p) - k (c - p) = 0,    F = sum_c D_c^T f_c,                       (3,)

    ``f_c`` the pad's world force on the block at contact ``c``, ``D_c = dm_c/dp``
    the pad point's motion by the plate's pose (``e_x``, ``e_y``, ``R'(p_theta -
    p_theta,0) rel_c``), ``c`` the commanded pose.  Differentiating it, with
    three more input directions of the same linearised step for ``dF/dp``,

        (dF/dp + diag k) dp = k dc + (c - p) dk - dF/d(input)|_p.

    ``commanded`` (4,) ``(c_x, c_y, h, c_theta)``, ``plate`` (3,) the converged
    ``p``; ``d_start`` (n_dofs, J), ``d_plate_start`` (4, J) ``(p_x, p_y, h,
    p_theta)`` at the start, ``d_commanded`` (4, J) at the end, ``d_params``
    (6, J), ``d_stiffness`` (3, J) of ``k``.  Returns ``(lin, derivative, dp)``
    (``derivative`` None if ``lin.failure``)."""
    origin = replace(state, upper_translation=np.array([*state.plate[:2], state.upper_translation[2]]),
                     upper_rotation=float(state.plate[2]))
    lin = PadLinearisation(model, origin, U, r, np.array([plate[0], plate[1], commanded[2]]), float(plate[2]))
    if lin.failure:
        return lin, None, None
    J, zeros = d_start.shape[1], np.zeros
    d_pose = zeros((4, J + 3))
    d_pose[2, :J] = d_commanded[2]
    d_pose[[0, 1, 3], J:] = np.eye(3)
    held = lin.solve_pad(np.hstack([d_start, zeros((d_start.shape[0], 3))]), np.hstack([d_plate_start, zeros((4, 3))]),
                         d_pose, np.hstack([d_params, zeros((6, 3))]))
    dF = lin.plate_force_derivative(held, d_start, d_plate_start, d_pose[3])
    k, c = np.asarray(model.gripper.stiffness, float), commanded[[0, 1, 3]]
    dp = np.linalg.solve(dF[:, J:] + np.diag(k), k[:, None] * d_commanded[[0, 1, 3]]
                         + (c - plate)[:, None] * d_stiffness - dF[:, :J])

    def combined(x):
        return x[..., :J] + x[..., J:] @ dp

    return lin, HeldDerivative(*(combined(x) for x in (held.displacement, held.reaction, held.upper_force,
                                                         held.contact_motion))), dp

