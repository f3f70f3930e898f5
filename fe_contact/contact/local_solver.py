"""Solvers of the condensed frictional contact problem (paper sect. 8, eq. 42-45).

Find per contact ``r`` (shape ``(n_contacts, 3)``, local ``(n, t_x, t_y)``) with

    u = W r + q,    r in K_mu,    modified(u) in K_mu*,    r . modified(u) = 0,

i.e. ``r = proj_K(r - rho * modified(u))`` for any ``rho > 0``, where ``K_mu`` is
the elliptic cone of :mod:`fe_contact.contact.friction` and ``modified(u) = (u_n +
||M u_t||, u_t)`` is De Saxcé's modified velocity.  ``W`` is symmetric positive
(semi)definite of size ``3 n_contacts``, blocks ordered like ``r``.

Methods
-------
``"uzawa"``
    The paper's Uzawa / bi-potential fixed point with its per-contact ``rho = 1
    / min(w_nn, w_txtx, w_tyty)`` (sect. 8), contact by contact (Gauss-Seidel):
    :mod:`fe_contact.contact.uzawa`.
``"uzawa_jacobi"``
    The same with all contacts updated at once, safeguarded by halving ``rho``.
``"newton"``
    Semismooth Newton on the Alart-Curnier equations of the equivalent problem
    with an isotropic cone per contact, ``r = D s``, ``D = diag(1, mu_x / mu,
    mu_y / mu)``, ``mu = max(mu_x, mu_y)`` (``D = I`` for isotropic contacts),
    with a normal and a tangential ``rho`` per contact, globalised by a
    non-monotone Armijo line search on ``|F|^2 / 2`` (the equations and the
    linear algebra of a step: :mod:`fe_contact.contact.alart_curnier`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .alart_curnier import (alart_curnier, factorise_newton_matrix, gmres, jacobian_product, lu_step, newton_matrix,
                            well_conditioned)
from .friction import _as_coefficients, _modified, _project, scaling_diagonal
from .uzawa import uzawa

__all__ = ["LocalSolution", "NewtonWorkspace", "solve_local", "natural_map_residual", "METHODS"]

METHODS = ("uzawa", "newton", "uzawa_jacobi")

_ARMIJO_SIGMA = 1e-4
_MIN_STEP = 2.0**-30
_NONMONOTONE_MEMORY = 5
_KRYLOV_RTOL = 1e-2  # relative residual of the linearised equations in a Krylov step
_KRYLOV_MAX_ITER = 20  # GMRES iterations before a new LU is cheaper (n^2 each against n^3)
# Below this order an LU costs less than the interpreter work of GMRES.  Measured (issue
# 32, benchmarks/krylov_order.py, one thread), the local phase of a press and three
# pushes, Krylov steps over an LU every Newton step: order 147 1.05-1.37x, 243 0.88-1.19x
# (a draw), 363 0.53-0.60x, 507 0.46-0.50x, 867 0.28-0.29x (1323: local_solvers.py).
_KRYLOV_MIN_ORDER = 300
STALL_RATIO = 0.5
"""A Newton solve given a ``stall`` window stops when the window did not halve the best residual before it."""


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
        self._scaled = None  # (W, mx, my, _isotropic_scaling(W, mx, my))
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
        if not _same_matrix(W, self._W) or not np.array_equal(self._d, d):
            self._W, self._d = W, d.copy()
            self.lu = None

    def scaling(self, W, mx, my) -> tuple:
        """:func:`_isotropic_scaling` of ``W`` and the coefficients, kept while they
        stay the same (a step's local solves share them)."""
        kept = self._scaled
        if kept is None or not (_same_matrix(W, kept[0]) and np.array_equal(mx, kept[1])
                                and np.array_equal(my, kept[2])):
            kept = self._scaled = (W, mx.copy(), my.copy(), _isotropic_scaling(W, mx, my))
        return kept[3]


def _same_matrix(W, other) -> bool:
    """The same buffer viewed the same way (np.asarray may rewrap it)."""
    return other is not None and (
        W.__array_interface__["data"][0] == other.__array_interface__["data"][0]
        and W.shape == other.shape
        and W.strides == other.strides
    )


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
    """:func:`natural_map_residual` with checked coefficient arrays (inner loops): twice a
    local Newton step, so with as few numpy calls as it takes (the norms as
    ``np.linalg.norm`` computes them, ``sqrt(x . x)``)."""
    if not (np.isfinite(r).all() and np.isfinite(u).all()):
        return float("inf")
    with np.errstate(over="ignore", invalid="ignore"):
        res = _norm(r - _project(r - _modified(u, mx, my), mx, my))
        scale = max(_norm(q), _norm(r), _norm(u))
    if not math.isfinite(scale):
        return float("inf")
    return float(res / scale) if scale > 0 else float(res)


def _norm(a: np.ndarray) -> float:
    """The 2-norm of ``a``'s entries, as ``np.linalg.norm(a)`` (``sqrt`` of the dot product)."""
    x = a.ravel()
    return math.sqrt(x.dot(x))


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
    method : {"uzawa", "newton", "uzawa_jacobi"}
    tol : float
        Target normalised natural-map residual.
    max_iter : int, optional
        Iteration limit (default 20000 Uzawa sweeps, 100 Newton steps).
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
    if max_iter is not None and (isinstance(max_iter, bool) or not isinstance(max_iter, Integral) or max_iter < 1):
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if isinstance(tol, bool) or not isinstance(tol, Real):
        raise ValueError(f"tol must be a real number, got {tol!r}")
    if workspace is not None and not isinstance(workspace, NewtonWorkspace):
        raise ValueError(f"workspace must be a NewtonWorkspace, got {type(workspace).__name__}")
    Wd, qa, mx, my, ra = _validate(W, q, mu_x, mu_y, r0)
    return solve_checked(Wd, qa, mx, my, ra, method, tol, max_iter, assume_spd, workspace)


def solve_checked(W, q, mx, my, r0, method: str, tol: float, max_iter: int | None = None, assume_spd: bool = False,
                  workspace: NewtonWorkspace | None = None, stall: int | None = None) -> LocalSolution:
    """:func:`solve_local` for input already checked: ``W`` a finite ndarray (3 n,
    3 n) with a non-negative diagonal, ``q`` and ``r0`` finite (n, 3), ``mx``, ``my``
    finite >= 0 (n,), ``method`` one of :data:`METHODS`, ``tol > 0``.  ``stall``
    (Newton only): give up (not converged) once that many steps in a row have not
    brought the residual below ``STALL_RATIO`` of its best before them (a caller
    with a cheaper next start: :mod:`fe_contact.stepping.pad_load`).

    The FE Newton loop calls it every iteration with the tangent's own ``W``
    (checked when the tangent was built) and the model's coefficients: the checks of
    :func:`solve_local` (a pass over the ``(3 n)^2`` entries of ``W``, coefficient
    arrays rebuilt twice) cost 0.1-1 ms a call, a tenth of a small model's step."""
    if q.shape[0] == 0:
        empty = np.zeros((0, 3))
        return LocalSolution(empty, empty, 0, 0.0, True, (), method)
    ra = _project(r0, mx, my)
    if method != "newton":
        return _uzawa(W, q, mx, my, ra, tol, 20000 if max_iter is None else int(max_iter), method)
    return _newton(W, q, mx, my, ra, tol, 100 if max_iter is None else int(max_iter), assume_spd, workspace, stall)


def _uzawa(W, q, mx, my, r, tol, max_iter, method) -> LocalSolution:
    r, u, it, residual, history = uzawa(W, q, mx, my, r, tol, max_iter,
                                        lambda r, u: _natural_map(r, u, q, mx, my), method == "uzawa")
    return LocalSolution(r, u, it, residual, residual <= tol, tuple(history), method)


def _stalled(history: list, window: int | None) -> bool:
    """Whether the last ``window`` residuals of ``history`` stayed above ``STALL_RATIO`` of the best before them."""
    return window is not None and len(history) > window and \
        min(history[-window:]) > STALL_RATIO * min(history[:-window])


def _newton(W, q, mx, my, r, tol, max_iter, assume_spd=False, workspace=None, stall=None) -> LocalSolution:
    n = q.shape[0]
    D, mu, fixed, rho, w_ref = workspace.scaling(W, mx, my) if workspace is not None else _isotropic_scaling(W, mx, my)
    d = D.ravel()
    qs = q * D
    # A singular W (rigid multibody problems, axes without friction) makes the
    # Newton matrix singular; proximal-point regularisation (solve
    # FC(W + eta I, q - eta s_k) and move s_k) keeps it invertible and has the
    # same fixed point.  An SPD W needs none.
    Ws = None if assume_spd else W * d[:, None] * d[None, :]  # formed only to test and regularise
    eta = 0.0 if assume_spd or well_conditioned(Ws) else 1e-2 * w_ref
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
    while residual > tol and it < max_iter and not _stalled(history, stall):
        # the operator and its scaling: D W D itself, regularised, or W and d
        Wp, dp = (Ws + eta * np.eye(3 * n), np.ones_like(d)) if eta > 0 else (W, d)
        ac = (Wp, dp, qs - eta * s, mu, rho, fixed)  # the Alart-Curnier problem of this round
        F, P, Q = alart_curnier(s, *ac)
        psi = 0.5 * float(F.ravel() @ F.ravel())
        # LU factors of a Newton matrix of this Wp, not necessarily taken at s
        lu = keep.lu if keep is not None else None
        merits: list[float] = []
        for _ in range(30 if eta > 0 else max_iter):
            if it >= max_iter:
                break
            merits.append(psi)
            step, lu = _newton_direction(F, P, Q, ac, lu, keep)
            s, (F, P, Q), psi = _line_search(s, step, psi, max(merits[-_NONMONOTONE_MEMORY:]), ac)
            it += 1
            residual = true_residual(s)
            history.append(residual)
            if residual <= tol or np.sqrt(2.0 * psi) <= 1e-3 * residual * max(np.linalg.norm(qs), 1e-300) \
                    or _stalled(history, stall):
                break
        if eta > 0:
            eta = max(0.2 * eta, 1e-10 * w_ref)
    # every exit follows a true_residual of the last s: r_final, u_final are its
    return LocalSolution(r_final, u_final, it, residual, residual <= tol, tuple(history), "newton")


def _isotropic_scaling(W, mx, my):
    """The isotropic problem of each contact and its Alart-Curnier parameters.

    ``D`` and ``mu`` from :func:`fe_contact.contact.friction.scaling_diagonal`:
    ``r = D s`` maps ``||s_t|| <= mu s_n`` onto ``K_mu``.

    ``rho = (rho_n, rho_t)`` per contact is the inverse of the normal
    diagonal entry and of the largest eigenvalue of the tangential 2x2 block
    of ``D W D`` (Siconos' "split spectral norm" choice), so that each
    contact's equations are of unit scale in both directions.  A contact
    without flexibility in a direction takes the mean positive diagonal.

    Returns
    -------
    D : ndarray, shape (n, 3)
    mu : ndarray, shape (n,)
    fixed : ndarray of bool, shape (n, 3)
        Scaled components pinned to zero (an axis with zero friction).
    rho : ndarray, shape (n, 2)
    w_ref : float
        Mean positive diagonal entry of ``D W D`` (the scale of the regularisation).
    """
    n = mx.shape[0]
    D, mu = scaling_diagonal(mx, my)
    fixed = np.column_stack([np.zeros(n, bool), D[:, 1:] == 0])
    d = D.ravel()
    diag = (np.diag(W) * d * d).reshape(n, 3)
    w_ref = float(diag[diag > 0].mean()) if np.any(diag > 0) else 1.0
    # largest eigenvalue of the symmetric tangential blocks [[a, b], [b, c]]
    idx = 3 * np.arange(n)
    b = W[idx + 1, idx + 2] * D[:, 1] * D[:, 2]
    a, c = diag[:, 1], diag[:, 2]
    w_t = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    w = np.column_stack([diag[:, 0], w_t])
    rho = 1.0 / np.where(w > 0, w, w_ref)
    return D, mu, fixed, rho, w_ref


def _newton_direction(F, P, Q, ac, lu, keep):
    """Semismooth Newton direction (n, 3) at ``s`` for the Alart-Curnier
    problem ``ac``, ``F, P, Q`` its :func:`alart_curnier` at ``s``, and the LU
    factors to precondition the next one.

    With ``lu`` (factors of an older Newton matrix) a Krylov step: GMRES on
    the generalised Jacobian at ``s``, applied without forming it (O(n^2) a
    product), preconditioned by ``lu``.  The Jacobian is piecewise constant in
    the stick / slip / open pattern and varies slowly within it, so the old
    factors usually make GMRES converge in a few products, where a new LU
    costs O(n^3).  Otherwise, or if GMRES fails, a new LU (kept in ``keep``).
    """
    n = F.shape[0]
    Wp, dp = ac[0], ac[1]
    step = None
    if lu is not None and 3 * n >= _KRYLOV_MIN_ORDER:
        step = gmres(lambda v: jacobian_product(P, Q, Wp, dp, v), -F.ravel(),
                     lambda v: lu_step(lu, v), _KRYLOV_RTOL, _KRYLOV_MAX_ITER)
        if step is not None:
            # rows that are e_i (open contacts, pinned components) are
            # solved exactly, so that an open contact's force is exactly 0
            exact = np.all(Q == 0.0, axis=2) & np.all(P == np.eye(3)[None], axis=2)
            step = np.where(exact.ravel(), -F.ravel(), step)
            if keep is not None:
                keep.krylov_steps += 1
    if step is None:
        lu = factorise_newton_matrix(newton_matrix(P, Q, Wp, dp))
        if keep is not None:
            keep.lu = lu
            keep.factorisations += 1
        if lu is not None:
            step = lu_step(lu, -F.ravel())
        else:  # lu_factor overwrote the matrix
            step = sla.lstsq(newton_matrix(P, Q, Wp, dp), -F.ravel(), check_finite=False)[0]
    return step.reshape(n, 3), lu


def _line_search(s, step, psi, ref, ac):
    """Non-monotone Armijo backtracking on ``psi = |F|^2 / 2`` against the
    reference merit ``ref`` (the largest of the last few): the new ``s``, its
    :func:`alart_curnier` ``(F, P, Q)`` (the blocks for the next direction: the
    compiled kernel gives them at the cost of ``F`` alone) and ``psi``."""
    alpha = 1.0
    while True:
        s_try = s + alpha * step
        ac_try = alart_curnier(s_try, *ac)
        F_try = ac_try[0]
        psi_try = 0.5 * float(F_try.ravel() @ F_try.ravel())
        if psi_try <= ref - 2.0 * _ARMIJO_SIGMA * alpha * psi or alpha <= _MIN_STEP:
            return s_try, ac_try, psi_try
        alpha *= 0.5
