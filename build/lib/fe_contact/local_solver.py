"""Solvers of the condensed frictional contact problem (paper sect. 8, eq. 42-45).

Find per contact ``r`` (shape ``(n_contacts, 3)``, local ``(n, t_x, t_y)``) with

    u = W r + q,    r in K_mu,    modified(u) in K_mu*,    r . modified(u) = 0,

i.e. ``r = proj_K(r - rho * modified(u))`` for any ``rho > 0``, where ``K_mu`` is
the elliptic cone of :mod:`fe_contact.friction` and ``modified(u) = (u_n +
||M u_t||, u_t)`` is De Saxcé's modified velocity.  ``W`` is symmetric positive
(semi)definite of size ``3 n_contacts``, blocks ordered like ``r``.

Methods
-------
``"uzawa"``
    The paper's Uzawa / bi-potential fixed point, all contacts updated at once
    with the per-contact ``rho = 1 / min(w_nn, w_txtx, w_tyty)`` of sect. 8,
    safeguarded: all ``rho`` are halved whenever the residual grows or stalls.
``"newton"``
    Semismooth Newton on the Alart-Curnier equations of the equivalent isotropic
    problem ``FC(D W D, D q, mu = 1)``, ``r = D s``, ``D = diag(1, mu_x, mu_y)``,
    globalised by a non-monotone Armijo line search on ``|F|^2 / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numba import njit

from ._threads import dense_kernel
from .friction import _as_coefficients, _modified, _project, project_elliptic_cone

__all__ = ["LocalSolution", "NewtonWorkspace", "solve_local", "natural_map_residual", "METHODS"]

METHODS = ("uzawa", "newton")

_ARMIJO_SIGMA = 1e-4
_MIN_STEP = 2.0**-30
_NONMONOTONE_MEMORY = 5
_GROWTH = 2.0  # residual growth that halves the Uzawa step
_BLOWUP = 1e6  # |r| beyond this many force scales is divergence
_STALL_CHECKS = 5  # checks (10 iterations each) ...
_STALL_RATIO = 0.9  # ... over which the residual must fall by 10 %
_KRYLOV_RTOL = 1e-2  # relative residual of the linearised equations in a Krylov step
_KRYLOV_MAX_ITER = 20  # GMRES iterations before a new LU is cheaper (n^2 each against n^3)
_KRYLOV_MIN_ORDER = 1000  # below, an LU costs less than the interpreter work of GMRES (planning mesh: 243)


@dataclass(frozen=True)
class LocalSolution:
    """Outcome of :func:`solve_local`.

    Attributes
    ----------
    r, u : ndarray, shape (n_contacts, 3)
        Reactions and (relative) velocities/displacement increments, local frames.
    iterations : int
        Iterations performed (fixed-point sweeps or Newton steps).
    residual : float
        Normalised natural-map residual of the returned ``r`` (see
        :func:`natural_map_residual`).
    converged : bool
        ``residual <= tol``.
    residual_history : tuple of float
        Residual after each recorded iteration.
    method : str
    """

    r: np.ndarray
    u: np.ndarray
    iterations: int
    residual: float
    converged: bool
    residual_history: tuple
    method: str


class NewtonWorkspace:
    """What the ``"newton"`` method keeps between calls on one flexibility matrix.

    A load step solves many local problems with the same ``W`` and a slowly
    changing ``q``.  The workspace keeps the LU factors of the last Newton
    matrix, which precondition GMRES on the next Newton matrices (Krylov
    steps: a few products instead of a dense LU).  Pass it with the same ``W``
    object, unmodified; another ``W`` or other coefficients reset it.

    Attributes
    ----------
    factorisations, krylov_steps : int
        Newton steps taken with a new dense LU factorisation, and with GMRES
        preconditioned by the kept one, so far.
    """

    def __init__(self) -> None:
        self._W = None
        self._d = None
        self.lu = None
        self.factorisations = 0
        self.krylov_steps = 0

    def copy(self) -> "NewtonWorkspace":
        """An independent workspace starting from this one's state (arrays shared, never modified)."""
        other = NewtonWorkspace()
        other.__dict__.update(self.__dict__)
        return other

    def _bind(self, W, d) -> None:
        """Forget the kept factors unless they belong to this ``W`` and scaling ``d``."""
        # "same W" = same buffer viewed the same way (np.asarray may rewrap it)
        same = self._W is not None and (
            W.__array_interface__["data"][0] == self._W.__array_interface__["data"][0]
            and W.shape == self._W.shape
            and W.strides == self._W.strides
        )
        if not same or not np.array_equal(self._d, d):
            self._W, self._d = W, d.copy()
            self.lu = None


def natural_map_residual(r, u, q, mu_x, mu_y) -> float:
    """``||r - proj_K(r - modified(u))|| / max(||q||, ||r||, ||u||)`` (the bare
    norm if all three are 0).

    The normalisation is the one of Siconos' ``fc3d_compute_error``.
    """
    r = np.asarray(r, dtype=float)
    u = np.asarray(u, dtype=float)
    n = r.shape[0]
    if n == 0:
        return 0.0
    mx, my = _as_coefficients(mu_x, mu_y, n)
    return _natural_map(r, u, q, mx, my)


def _natural_map(r, u, q, mx, my) -> float:
    """:func:`natural_map_residual` with checked coefficient arrays (inner loops)."""
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(u))):
        return float("inf")
    with np.errstate(over="ignore", invalid="ignore"):
        res = np.linalg.norm(r - _project(r - _modified(u, mx, my), mx, my))
        scale = max(np.linalg.norm(q), np.linalg.norm(r), np.linalg.norm(u))
    if not np.isfinite(scale):
        return float("inf")
    return float(res / scale) if scale > 0 else float(res)


def _validate(W, q, mu_x, mu_y, r0):
    qa = np.asarray(q, dtype=float)
    if qa.ndim == 1:
        if qa.size % 3:
            raise ValueError(f"q must have shape (n_contacts, 3) or (3 n_contacts,), got {qa.shape}")
        qa = qa.reshape(-1, 3)
    if qa.ndim != 2 or qa.shape[1] != 3:
        raise ValueError(f"q must have shape (n_contacts, 3), got {qa.shape}")
    n = qa.shape[0]
    Wd = W.toarray() if sp.issparse(W) else np.asarray(W, dtype=float)
    if Wd.ndim != 2 or Wd.shape[0] != Wd.shape[1]:
        raise ValueError(f"W must be square, got shape {Wd.shape}")
    if Wd.shape[0] != 3 * n:
        raise ValueError(f"W has shape {Wd.shape} but q has {n} contacts (expected {3 * n} rows)")
    if not np.all(np.isfinite(Wd)):
        raise ValueError("W contains non-finite values")
    if not np.all(np.isfinite(qa)):
        raise ValueError("q contains non-finite values")
    if np.any(np.diag(Wd) < 0):
        raise ValueError(f"W must have a non-negative diagonal, got min {np.diag(Wd).min()}")
    mx, my = _as_coefficients(mu_x, mu_y, n)
    if r0 is None:
        ra = np.zeros((n, 3))
    else:
        ra = np.array(r0, dtype=float).reshape(-1, 3) if np.size(r0) == 3 * n else None
        if ra is None:
            raise ValueError(f"r0 must have shape ({n}, 3), got {np.shape(r0)}")
        if not np.all(np.isfinite(ra)):
            raise ValueError("r0 contains non-finite values")
    return Wd, qa, mx, my, ra


def solve_local(
    W,
    q,
    mu_x,
    mu_y,
    method: str = "uzawa",
    tol: float = 1e-10,
    max_iter: int | None = None,
    r0=None,
    assume_spd: bool = False,
    workspace: NewtonWorkspace | None = None,
) -> LocalSolution:
    """Solve the condensed frictional contact problem ``FC(W, q, M)``.

    Parameters
    ----------
    W : array_like or sparse, shape (3 n, 3 n)
        Flexibility matrix in the local frames (symmetric positive semidefinite).
    q : array_like, shape (n, 3) or (3 n,)
        Free displacement (velocity) of the contacts, ``u = W r + q``.
    mu_x, mu_y : float or array_like, shape (n,)
        Friction coefficients along the local axes (>= 0).
    method : {"uzawa", "newton"}
    tol : float
        Target normalised natural-map residual.
    max_iter : int, optional
        Iteration limit (default 20000 for Uzawa, 100 for Newton).
    r0 : array_like, shape (n, 3), optional
        Initial reactions (warm start); projected onto the cone first.
    assume_spd : bool
        The caller knows ``W`` is symmetric positive definite (an FE
        flexibility matrix): the Newton method skips its conditioning test and
        proximal regularisation.
    workspace : NewtonWorkspace, optional
        Newton only: reuse the factorised Newton matrix of earlier calls with
        the same ``W`` object as a GMRES preconditioner (Krylov steps).

    Returns
    -------
    LocalSolution
        ``converged`` is False (never an exception) when the limit is reached.

    Raises
    ------
    ValueError
        Non-square or mismatched ``W``, non-finite data, negative ``mu``,
        unknown method, non-positive ``tol``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be > 0, got {tol}")
    if max_iter is not None and int(max_iter) < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    if workspace is not None and not isinstance(workspace, NewtonWorkspace):
        raise ValueError(f"workspace must be a NewtonWorkspace, got {type(workspace).__name__}")
    Wd, qa, mx, my, ra = _validate(W, q, mu_x, mu_y, r0)
    if qa.shape[0] == 0:
        empty = np.zeros((0, 3))
        return LocalSolution(empty, empty, 0, 0.0, True, (), method)
    ra = project_elliptic_cone(ra, mx, my)
    if method == "uzawa":
        return _uzawa(Wd, qa, mx, my, ra, tol, 20000 if max_iter is None else int(max_iter))
    return _newton(Wd, qa, mx, my, ra, tol, 100 if max_iter is None else int(max_iter), assume_spd, workspace)


def _uzawa(W, q, mx, my, r, tol, max_iter) -> LocalSolution:
    n = q.shape[0]
    diag = np.diag(W).reshape(n, 3)
    positive = np.where(diag > 0, diag, np.inf)
    wmin = positive.min(axis=1)
    # a contact with no flexibility at all does not move: any rho works
    rho = np.where(np.isfinite(wmin), 1.0 / np.where(np.isfinite(wmin), wmin, 1.0), 1.0)[:, None]
    # The paper's rho makes the simultaneous update a contraction only when W is
    # close to block diagonal.  A flexibility matrix of a continuum is not (one
    # nodal force moves its neighbours almost as much as itself), and the plain
    # iteration then diverges or cycles.  Safeguard: when the residual grows, or
    # falls by less than _STALL_RATIO over _STALL_CHECKS checks, restart from the
    # best iterate with all rho halved (omega below).
    omega = 1.0
    history = []
    check_every = 10
    best_r, best_res = r, np.inf
    segment: list[float] = []  # residuals since the last restart
    # force scale of the problem: a solution is far below _BLOWUP times this
    r_ref = max(np.linalg.norm(r), np.linalg.norm(rho * q), 1e-300)
    it = 0
    while it < max_iter:
        u = (W @ r.ravel()).reshape(n, 3) + q
        if it % check_every == 0:
            residual = _natural_map(r, u, q, mx, my)
            history.append(residual)
            if residual <= tol:
                break
            if residual < best_res and np.linalg.norm(r) <= _BLOWUP * r_ref:
                best_r, best_res = r, residual
            segment.append(residual)
            stalled = len(segment) > _STALL_CHECKS and residual > _STALL_RATIO * segment[-_STALL_CHECKS - 1]
            # the normalised residual shrinks as |r| blows up, so size guards it too
            blown_up = np.linalg.norm(r) > _BLOWUP * r_ref
            if not np.isfinite(residual) or residual > _GROWTH * best_res or stalled or blown_up:
                omega *= 0.5
                r = best_r
                u = (W @ r.ravel()).reshape(n, 3) + q
                segment = []
        r = _project(r - omega * rho * _modified(u, mx, my), mx, my)
        it += 1
    u = (W @ r.ravel()).reshape(n, 3) + q
    residual = _natural_map(r, u, q, mx, my)
    if residual > best_res:
        r, residual = best_r, best_res
        u = (W @ r.ravel()).reshape(n, 3) + q
    history.append(residual)
    return LocalSolution(r, u, it, residual, residual <= tol, tuple(history), "uzawa")


def _alart_curnier(s, W, d, qs, mu, rho, fixed, jacobian=True):
    """AC function ``F(s)`` and (if ``jacobian``) one element of its generalised
    Jacobian, ``blockdiag(P) + blockdiag(Q) D W D``, as its 3x3 blocks ``P, Q``
    (n, 3, 3) (:func:`_newton_matrix` forms it, :func:`_jacobian_product`
    applies it).

    Isotropic cone with coefficients ``mu`` (1 or 0) on the scaled variables
    of the problem ``u_s = D W D s + q_s``, ``D = diag(d)`` (``D W D`` is never
    formed: at 1e4 contacts it is another 7 GB matrix).  ``fixed`` marks
    scaled components pinned to 0 (axes with zero friction).  The product
    with ``W`` is BLAS; the per-contact rest is :func:`_ac_kernel`.
    """
    n = s.shape[0]
    u = (d * (W @ (d * s.ravel()))).reshape(n, 3) + qs
    size = n if jacobian else 0
    P, Q = np.zeros((size, 3, 3)), np.zeros((size, 3, 3))
    F = _ac_kernel(np.ascontiguousarray(s), u, mu, rho, fixed, P, Q)
    return (F, P, Q) if jacobian else F


@njit(cache=True)
def _ac_kernel(s, u, mu, rho, fixed, P, Q):
    """``F`` of :func:`_alart_curnier` for displacements ``u``, and its
    Jacobian blocks into ``P``, ``Q`` (zeroed, shape (n, 3, 3)) unless they
    have no rows.

    Per contact, with ``p = s_n - rho u_n``, ``R = mu max(p, 0)``, ``z = s_t -
    rho u_t``; the Jacobian is ``blockdiag(P) + Q W_s``:

    * normal row, active (p > 0): ``rho W_n`` (P = 0, Q = rho e_n);
      inactive: ``e_n`` (P = e_n, Q = 0);
    * tangent rows, stick (|z| <= R, R > 0): ``rho W_t`` (P = 0, Q = rho [0 I]);
      slide: ``E_t - zhat dR^T - R/|z| (I - zhat zhat^T)(E_t - rho W_t)`` with
      ``dR = mu (e_n - rho W_n)`` when active, else 0;
    * components pinned to zero: ``F = s``, row ``e_i``.
    """
    n = s.shape[0]
    F = np.empty((n, 3))
    jac = P.shape[0] > 0
    for c in range(n):
        r = rho[c]
        p = s[c, 0] - r * u[c, 0]
        active = p > 0.0
        R = mu[c] * p if active else 0.0
        z1 = s[c, 1] - r * u[c, 1]
        z2 = s[c, 2] - r * u[c, 2]
        zn = math.sqrt(z1 * z1 + z2 * z2)
        stick = zn <= R and R > 0.0
        h1, h2 = (z1 / zn, z2 / zn) if zn > 0.0 else (0.0, 0.0)
        F[c, 0] = r * u[c, 0] if active else s[c, 0]
        if stick:
            F[c, 1], F[c, 2] = r * u[c, 1], r * u[c, 2]
        else:
            F[c, 1], F[c, 2] = s[c, 1] - R * h1, s[c, 2] - R * h2
        if jac:
            if active:
                Q[c, 0, 0] = r
            else:
                P[c, 0, 0] = 1.0
            if stick:
                Q[c, 1, 1] = r
                Q[c, 2, 2] = r
            else:
                coef = R / zn if zn > 0.0 else 0.0
                m_act = mu[c] if active else 0.0
                h = (h1, h2)
                for i in range(2):
                    P[c, 1 + i, 0] = -m_act * h[i]
                    Q[c, 1 + i, 0] = m_act * r * h[i]
                    for j in range(2):
                        proj = (1.0 if i == j else 0.0) - h[i] * h[j]
                        P[c, 1 + i, 1 + j] = (1.0 if i == j else 0.0) - coef * proj
                        Q[c, 1 + i, 1 + j] = coef * r * proj
        for i in range(3):
            if fixed[c, i]:
                F[c, i] = s[c, i]
                if jac:
                    for j in range(3):
                        P[c, i, j] = 1.0 if i == j else 0.0
                        Q[c, i, j] = 0.0
    return F


def _newton_matrix(P, Q, W, d) -> np.ndarray:
    """The dense Jacobian ``blockdiag(P) + blockdiag(Q) D W D``, (3n, 3n)."""
    n = P.shape[0]
    m = 3 * n
    J = np.einsum("cij,cjm->cim", Q * d.reshape(n, 1, 3), W.reshape(n, 3, m)).reshape(m, m)
    J *= d
    blocks = J.reshape(n, 3, n, 3)
    idx = np.arange(n)
    blocks[idx, :, idx, :] += P
    return J


def _jacobian_product(P, Q, W, d, v) -> np.ndarray:
    """``(blockdiag(P) + blockdiag(Q) D W D) v`` without forming the matrix (3n,)."""
    n = P.shape[0]
    Wv = (d * (W @ (d * v))).reshape(n, 3)
    return (np.einsum("cij,cj->ci", P, v.reshape(n, 3)) + np.einsum("cij,cj->ci", Q, Wv)).ravel()


def _gmres(apply_A, b, apply_M, rtol: float, max_iter: int) -> np.ndarray | None:
    """``x`` with ``|A x - b| <= rtol |b|`` by GMRES right-preconditioned with
    ``M^-1`` (``apply_M``), from ``x = 0``; None if ``max_iter`` iterations do
    not get there.  Arnoldi by classical Gram-Schmidt applied twice (two
    matrix products per iteration instead of a loop over the basis)."""
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


def _well_conditioned(A) -> bool:
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


def _factorise(J):
    """LU factors of the (C-ordered) Newton matrix ``J``, or None if it is exactly
    singular.  LAPACK factorises ``J^T``, which is ``J`` in Fortran order, in
    place: no copy.  Solve with :func:`_lu_step`."""
    with dense_kernel(J.shape[0]):
        lu, piv = sla.lu_factor(J.T, overwrite_a=True, check_finite=False)
    if not np.all(np.isfinite(lu)) or np.any(np.diag(lu) == 0.0):
        return None
    return lu, piv


def _lu_step(lu, rhs):
    """``J^-1 rhs`` from the factors of ``J^T`` (:func:`_factorise`)."""
    return sla.lu_solve(lu, rhs, trans=1, check_finite=False)


def _newton(W, q, mx, my, r, tol, max_iter, assume_spd=False, workspace=None) -> LocalSolution:
    n = q.shape[0]
    frictionless = (mx == 0) & (my == 0)
    # D = diag(1, mu_x, mu_y); frictionless contacts keep D = I with mu = 0
    D = np.column_stack([np.ones(n), np.where(frictionless, 1.0, mx), np.where(frictionless, 1.0, my)])
    mu = np.where(frictionless, 0.0, 1.0)
    fixed = np.column_stack([np.zeros(n, bool), D[:, 1:] == 0])
    d = D.ravel()
    qs = q * D
    diag = (np.diag(W) * d * d).reshape(n, 3)
    w_ref = float(diag[diag > 0].mean()) if np.any(diag > 0) else 1.0
    rho = np.full(n, 1.0 / w_ref)
    # A singular W (rigid multibody problems, axes without friction) makes the
    # Newton matrix singular; proximal-point regularisation (solve
    # FC(W + eta I, q - eta s_k) and move s_k) keeps it invertible and has the
    # same fixed point.  An SPD W needs none.
    Ws = None if assume_spd else W * d[:, None] * d[None, :]  # formed only to test and regularise
    eta = 0.0 if assume_spd or _well_conditioned(Ws) else 1e-2 * w_ref
    # the factorised Newton matrix outlives the call only for an unregularised W
    keep = workspace if workspace is not None and eta == 0.0 else None
    if keep is not None:
        keep._bind(W, d)

    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(D > 0, r / np.where(D > 0, D, 1.0), 0.0)

    def true_residual(s):
        # measured on the projected iterate, which is what is returned: a Newton
        # iterate can sit slightly outside the cone, and projecting it afterwards
        # could undo a convergence decided on the unprojected one
        nonlocal r_final, u_final
        r_final = _project(s * D, mx, my)
        u_final = (W @ r_final.ravel()).reshape(n, 3) + q
        return _natural_map(r_final, u_final, q, mx, my)

    r_final = u_final = None  # the projected last iterate and its displacement
    residual = true_residual(s)
    history = [residual]
    it = 0
    while residual > tol and it < max_iter:
        # the operator and its scaling: D W D itself, regularised, or W and d
        Wp, dp = (Ws + eta * np.eye(3 * n), np.ones_like(d)) if eta > 0 else (W, d)
        qp = qs - eta * s
        F = _alart_curnier(s, Wp, dp, qp, mu, rho, fixed, jacobian=False)
        psi = 0.5 * float(F.ravel() @ F.ravel())
        # LU factors of a Newton matrix of this Wp, not necessarily taken at s
        lu = keep.lu if keep is not None else None
        merits: list[float] = []
        for _ in range(30 if eta > 0 else max_iter):
            if it >= max_iter:
                break
            merits.append(psi)
            step = None
            _, P, Q = _alart_curnier(s, Wp, dp, qp, mu, rho, fixed)
            if lu is not None and 3 * n >= _KRYLOV_MIN_ORDER:
                # Krylov step: GMRES on the generalised Jacobian at s, applied
                # without forming it (O(n^2) a product), preconditioned by the
                # LU factors of an older Newton matrix.  The Jacobian is
                # piecewise constant in the stick / slip / open pattern and
                # varies slowly within it, so the old factors usually make GMRES
                # converge in a few products, where a new LU costs O(n^3).
                step = _gmres(lambda v: _jacobian_product(P, Q, Wp, dp, v), -F.ravel(),
                              lambda v: _lu_step(lu, v), _KRYLOV_RTOL, _KRYLOV_MAX_ITER)
                if step is not None:
                    # rows that are e_i (open contacts, pinned components) are
                    # solved exactly, so that an open contact's force is exactly 0
                    exact = np.all(Q == 0.0, axis=2) & np.all(P == np.eye(3)[None], axis=2)
                    step = np.where(exact.ravel(), -F.ravel(), step)
                    if keep is not None:
                        keep.krylov_steps += 1
            if step is None:
                lu = _factorise(_newton_matrix(P, Q, Wp, dp))
                if keep is not None:
                    keep.lu = lu
                    keep.factorisations += 1
                if lu is not None:
                    step = _lu_step(lu, -F.ravel())
                else:  # lu_factor overwrote the matrix
                    step = sla.lstsq(_newton_matrix(P, Q, Wp, dp), -F.ravel(), check_finite=False)[0]
            step = step.reshape(n, 3)
            ref = max(merits[-_NONMONOTONE_MEMORY:])
            alpha = 1.0
            while True:
                s_try = s + alpha * step
                F_try = _alart_curnier(s_try, Wp, dp, qp, mu, rho, fixed, jacobian=False)
                psi_try = 0.5 * float(F_try.ravel() @ F_try.ravel())
                if psi_try <= ref - 2.0 * _ARMIJO_SIGMA * alpha * psi or alpha <= _MIN_STEP:
                    break
                alpha *= 0.5
            s, F, psi = s_try, F_try, psi_try
            it += 1
            residual = true_residual(s)
            history.append(residual)
            if residual <= tol or np.sqrt(2.0 * psi) <= 1e-3 * residual * max(np.linalg.norm(qs), 1e-300):
                break
        if eta > 0:
            eta = max(0.2 * eta, 1e-10 * w_ref)
    # every exit follows a true_residual of the last s: r_final, u_final are its
    return LocalSolution(r_final, u_final, it, residual, residual <= tol, tuple(history), "newton")
