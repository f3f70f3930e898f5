"""Linearisation of the converged elliptic Coulomb law at one contact, for the
sensitivities of a step (implicit function theorem,
:mod:`fe_contact.stepping.sensitivity`).

At a solution of the De Saxce law ``r = proj_K(r - rho modified(u))``
(paper eq. 42-45; local ``(n, t_x, t_y)``, ``r`` N, ``u`` m: the normal gap
and the tangential displacement increment of the step) each contact is on
one branch of the projection, and the law is there a smooth equation
``A dr + B du + B_mu dmu = 0`` (3 rows per contact):

* separated (``r = 0``, polar branch):      ``dr = 0``;
* stick (``r`` inside ``K_mu``):             ``du = 0``;
* slip (``r`` on the cone's boundary, ``u_t != 0``): the gap stays closed,
  ``du_n = 0``, and the force follows the associated slip rule (paper
  eq. 23-30, the normal of ``||M^-1 r_t|| = r_n``)

      r_t = -r_n s(u_t, mu),    s = M^2 u_t / ||M u_t||,   M = diag(mu_x, mu_y),

  whose differential is ``dr_t + s dr_n + r_n ds/du_t du_t + r_n ds/dmu dmu = 0``
  with ``ds/du_t = M (I - v v^T / |v|^2) M / |v|``, ``v = M u_t``.

These are the elements of the semismooth (B-) Jacobian of the natural map on
each branch.  At a transition (a node exactly on the border between two
branches: sticking at the cone's edge, or touching with zero force) the law
is not differentiable; the branch is the one the step reports
(:func:`fe_contact.stepping.measure.node_status`) and the derivative is the
one-sided derivative from that side.
"""

from __future__ import annotations

import numpy as np

__all__ = ["law_jacobian"]


def law_jacobian(separated: np.ndarray, slip: np.ndarray, r: np.ndarray, u_t: np.ndarray, mu_x: float,
                 mu_y: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blocks of the linearised contact law ``A dr + B du + B_mu (dmu_x, dmu_y) = 0``.

    Parameters
    ----------
    separated, slip : ndarray of bool, shape (n,)
        Branch of each contact (the others stick).
    r : ndarray, shape (n, 3)
        Converged local forces ``(r_n, r_tx, r_ty)``, N.
    u_t : ndarray, shape (n, 2)
        Tangential displacement increments of the step in ``(t_x, t_y)``, m.
    mu_x, mu_y : float or ndarray, shape (n,)
        Friction coefficients (one per contact: each body its own cone).

    Returns
    -------
    A : ndarray, shape (n, 3, 3)
        Coefficients of ``dr``, dimensionless.
    B : ndarray, shape (n, 3, 3)
        Coefficients of ``du``, N/m on slip rows, 1 on stick rows.
    B_mu : ndarray, shape (n, 3, 2)
        Coefficients of ``(dmu_x, dmu_y)``, N.
    """
    n = r.shape[0]
    eye = np.eye(3)
    A = np.zeros((n, 3, 3))
    B = np.zeros((n, 3, 3))
    B_mu = np.zeros((n, 3, 2))
    stick = ~separated & ~slip
    A[separated] = eye
    B[stick] = eye
    if not slip.any():
        return A, B, B_mu
    m = np.broadcast_to(np.stack(np.broadcast_arrays(mu_x, mu_y), axis=-1), (n, 2))[slip]  # (k, 2)
    u = u_t[slip]
    v = m * u  # M u_t (k, 2)
    nv = np.linalg.norm(v, axis=1)
    nv = np.where(nv > 0, nv, 1.0)
    s = m * v / nv[:, None]  # M^2 u_t / ||M u_t||
    P = np.eye(2) - np.einsum("ki,kj->kij", v, v) / (nv**2)[:, None, None]
    ds_du = m[:, :, None] * P * m[:, None, :] / nv[:, None, None]
    # ds_i/dmu_j = delta_ij 2 mu_j u_j / |v| - s_i mu_j u_j^2 / |v|^2
    ds_dmu = (np.eye(2) * (2.0 * m * u / nv[:, None])[:, None, :]
              - s[:, :, None] * (m * u**2 / (nv**2)[:, None])[:, None, :])
    rn = r[slip, 0][:, None, None]
    As = np.zeros((u.shape[0], 3, 3))
    As[:, 1:, 0] = s
    As[:, 1, 1] = As[:, 2, 2] = 1.0
    Bs = np.zeros((u.shape[0], 3, 3))
    Bs[:, 0, 0] = 1.0  # du_n = 0: the gap stays closed
    Bs[:, 1:, 1:] = rn * ds_du
    A[slip], B[slip] = As, Bs
    B_mu[slip, 1:, :] = rn * ds_dmu
    return A, B, B_mu
