"""Alart-Curnier equations of the isotropic frictional contact problem and the
linear algebra of a semismooth Newton step on them (the ``"newton"`` method of
:mod:`fe_contact.contact.local_solver`).

For scaled forces ``s`` (n, 3), ordered ``(n, t_x, t_y)``, with
``u_s = D W D s + q_s`` and per contact a normal and a tangential
``rho_n, rho_t > 0``:

    F_n(s) = s_n - max(0, s_n - rho_n u_n),
    F_t(s) = s_t - proj_{|z| <= mu max(0, s_n - rho_n u_n)}(z),   z = s_t - rho_t u_t,

and ``F(s) = 0`` exactly when ``s`` solves the contact problem with an
isotropic cone of coefficient ``mu`` (Alart and Curnier, CMAME 92:353-375,
1991).  An element of its generalised Jacobian is
``blockdiag(P) + blockdiag(Q) D W D`` (3 n, 3 n), given as its 3x3 blocks
``P, Q`` (n, 3, 3).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from ..linalg.threads import dense_kernel
from ._kernels import _ac_kernel, _newton_matrix_kernel  # compiled (_kernels.pyx)


def alart_curnier(s, W, d, qs, mu, rho, fixed, jacobian=True):
    """AC function ``F(s)`` and (if ``jacobian``) one element of its generalised
    Jacobian, ``blockdiag(P) + blockdiag(Q) D W D``, as its 3x3 blocks ``P, Q``
    (n, 3, 3) (:func:`newton_matrix` forms it, :func:`jacobian_product`
    applies it).

    Isotropic cone with coefficients ``mu`` (n,) on the scaled variables
    of the problem ``u_s = D W D s + q_s``, ``D = diag(d)`` (``D W D`` is never
    formed: at 1e4 contacts it is another 7 GB matrix).  ``fixed`` marks
    scaled components pinned to 0 (axes with zero friction); ``rho`` (n, 2)
    holds ``(rho_n, rho_t)`` per contact.  The product
    with ``W`` is BLAS; the per-contact rest is :func:`_ac_kernel`.
    """
    n = s.shape[0]
    u = (d * (W @ (d * s.ravel()))).reshape(n, 3) + qs
    size = n if jacobian else 0
    P, Q = np.zeros((size, 3, 3)), np.zeros((size, 3, 3))
    F = _ac_kernel(np.ascontiguousarray(s), u, mu, rho, np.asarray(fixed, dtype=bool).view(np.uint8), P, Q)
    return (F, P, Q) if jacobian else F


def newton_matrix(P, Q, W, d) -> np.ndarray:
    """The dense Jacobian ``blockdiag(P) + blockdiag(Q) D W D``, (3n, 3n), C order: row
    ``3 c + i`` is ``(sum_j Q[c, i, j] d_j W[3 c + j, :]) d``, ``P[c]`` added to its diagonal
    block, in one compiled pass (:func:`_newton_matrix_kernel`)."""
    m = 3 * P.shape[0]
    J = np.empty((m, m))
    _newton_matrix_kernel(P, Q, np.ascontiguousarray(W, dtype=float), np.ascontiguousarray(d, dtype=float), J)
    return J


def jacobian_product(P, Q, W, d, v) -> np.ndarray:
    """``(blockdiag(P) + blockdiag(Q) D W D) v`` without forming the matrix (3n,)."""
    n = P.shape[0]
    Wv = (d * (W @ (d * v))).reshape(n, 3)
    return (np.einsum("cij,cj->ci", P, v.reshape(n, 3)) + np.einsum("cij,cj->ci", Q, Wv)).ravel()


def gmres(apply_A, b, apply_M, rtol: float, max_iter: int) -> np.ndarray | None:
    """``x`` with ``|A x - b| <= rtol |b|`` by GMRES right-preconditioned with
    ``M^-1`` (``apply_M``), from ``x = 0``; None if ``max_iter`` iterations do
    not get there or a product is not finite (the caller then factorises).
    Arnoldi by classical Gram-Schmidt applied twice (two matrix products per
    iteration instead of a loop over the basis)."""
    beta = float(np.linalg.norm(b))
    if beta == 0.0:
        return np.zeros_like(b)
    V = np.zeros((max_iter + 1, b.size))
    H = np.zeros((max_iter + 1, max_iter))
    V[0] = b / beta
    rhs = np.zeros(max_iter + 1)
    rhs[0] = beta
    for j in range(max_iter):
        w = apply_A(apply_M(V[j]))
        if not np.all(np.isfinite(w)):  # overflowed (old factors of a nearly singular matrix)
            return None
        h = V[:j + 1] @ w
        w -= h @ V[:j + 1]
        h2 = V[:j + 1] @ w
        w -= h2 @ V[:j + 1]
        H[:j + 1, j] = h + h2
        H[j + 1, j] = np.linalg.norm(w)
        y, *_ = np.linalg.lstsq(H[:j + 2, :j + 1], rhs[:j + 2], rcond=None)
        ratio = float(np.linalg.norm(H[:j + 2, :j + 1] @ y - rhs[:j + 2])) / beta
        if ratio <= rtol:
            return apply_M(y @ V[:j + 1])
        if H[j + 1, j] <= 1e-14 * beta:  # invariant subspace without the solution
            return None
        # give up early when the rate so far would not reach rtol in max_iter
        if j >= 2 and (ratio >= 1.0 or (j + 1) * math.log(rtol) / math.log(ratio) > max_iter):
            return None
        V[j + 1] = w / H[j + 1, j]
    return None


def well_conditioned(A) -> bool:
    """Cheap test that the symmetric matrix ``A`` is safely positive definite.

    The smallest Cholesky pivot squared bounds the smallest eigenvalue from above
    only loosely, so this errs towards regularising, which costs iterations, not
    accuracy.
    """
    try:
        L = np.linalg.cholesky(0.5 * (A + A.T))
    except np.linalg.LinAlgError:
        return False
    return bool(np.min(np.diag(L)) ** 2 > 1e-8 * np.max(np.diag(A)))


def factorise_newton_matrix(J):
    """LU factors of the (C-ordered) Newton matrix ``J``, or None if it is exactly
    singular.  LAPACK factorises ``J^T``, which is ``J`` in Fortran order, in
    place: no copy.  Solve with :func:`lu_step`.  LAPACK's ``dgetrf`` / ``dgetrs``
    are called directly, as ``scipy.linalg.lu_factor`` / ``lu_solve`` call them
    (the same numbers) without their wrappers' checks, which cost as much as the
    factorisation at a planning mesh's order 147."""
    with dense_kernel(J.shape[0]):
        lu, piv, info = _getrf(J.T, overwrite_a=True)
    if info < 0 or not np.isfinite(lu).all() or (np.diagonal(lu) == 0.0).any():
        return None
    return lu, piv


def lu_step(lu, rhs):
    """``J^-1 rhs`` from the factors of ``J^T`` (:func:`factorise_newton_matrix`)."""
    x, info = _getrs(lu[0], lu[1], rhs, trans=1)
    if info != 0:
        raise ValueError(f"dgetrs: illegal value in argument {-info}")
    return x


_getrf, _getrs = sla.get_lapack_funcs(("getrf", "getrs"), dtype=np.float64)
