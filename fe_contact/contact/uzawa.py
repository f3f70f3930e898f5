"""The paper's Uzawa / bi-potential fixed point (sect. 8, eq. 42-45) for the
condensed problem ``u = W r + q`` of :mod:`fe_contact.contact.local_solver`.

Each contact ``c`` is updated by

    r_c <- proj_K(r_c - rho_c modified(u_c)),   rho_c = 1 / min(w_nn, w_txtx, w_tyty)   (eq. 44),

with ``modified(u) = (u_n + ||M u_t||, u_t)`` (De Saxcé) and the diagonal
entries ``w`` of the contact's own 3x3 block of ``W`` (m/N, so ``rho`` is in
N/m).  Two orders of the updates:

``"uzawa"`` (Gauss-Seidel, the paper's)
    contact by contact, each ``u_c = q_c + W_c r`` seeing the reactions already
    updated in this sweep.  Converges with the paper's ``rho`` unchanged on the
    paper case.
``"uzawa_jacobi"``
    all contacts at once from the same ``u = W r + q``.  ``W`` of a continuum is
    far from block diagonal (one nodal force moves its neighbours almost as much
    as itself) and the plain iteration diverges or cycles: it is safeguarded by
    halving all ``rho`` whenever the residual grows or stalls.

Both keep the best iterate and restart from it with halved ``rho`` on growth,
stall or blow-up, so that a problem they cannot solve ends as a reported
non-convergence, never as an overflow.
"""

from __future__ import annotations

import numpy as np

from ._kernels import _gauss_seidel_sweeps  # compiled: eq. 44 contact by contact (_kernels.pyx)
from .friction import _modified, _project

_GROWTH = 2.0  # residual growth that halves the Jacobi step ...
_GROWTH_GS = 100.0  # ... and the Gauss-Seidel one, whose residual is not monotone in its first sweeps
_BLOWUP = 1e6  # |r| beyond this many force scales is divergence
_STALL_CHECKS = 5  # checks ...
_STALL_RATIO = 0.9  # ... over which the residual must fall by 10 %


def paper_rho(W) -> np.ndarray:
    """``rho_c = 1 / min(w_nn, w_txtx, w_tyty)`` per contact (n,), over the positive
    diagonal entries (a contact with no flexibility at all does not move: 1)."""
    n = W.shape[0] // 3
    diag = np.diag(W).reshape(n, 3)
    wmin = np.where(diag > 0, diag, np.inf).min(axis=1)
    return np.where(np.isfinite(wmin), 1.0 / np.where(np.isfinite(wmin), wmin, 1.0), 1.0)


def _stick_inverses(W, n) -> np.ndarray:
    """Inverses of the contacts' 3x3 diagonal blocks of ``W`` (n, 3, 3); a
    singular block gets zeros (its stick reaction 0 is tried, harmlessly)."""
    idx = 3 * np.arange(n)[:, None] + np.arange(3)
    blocks = W[idx[:, :, None], idx[:, None, :]]
    ok = np.abs(np.linalg.det(blocks)) > 1e-12 * np.maximum(np.abs(blocks).max(axis=(1, 2)), 1e-300) ** 3
    inv = np.zeros_like(blocks)
    inv[ok] = np.linalg.inv(blocks[ok])
    return inv


def uzawa(W, q, mx, my, r, tol, max_iter, residual, gauss_seidel=True):
    """Safeguarded Uzawa (module docstring) from ``r`` (n, 3), on checked input.

    ``residual(r, u)`` is the natural-map residual, checked after every sweep
    (Gauss-Seidel) or every 10 (Jacobi).  Safeguards:

    * a residual that is not finite, or reactions ``_BLOWUP`` times the
      problem's force scale: restart from the best iterate with ``rho`` halved;
    * Jacobi: a residual ``_GROWTH`` times the best, or one that falls by less
      than ``_STALL_RATIO`` over ``_STALL_CHECKS`` checks, likewise;
    * Gauss-Seidel: a stall over ``10 _STALL_CHECKS`` sweeps first turns on
      the exact local stick solution (:func:`_gauss_seidel_sweeps`), which
      large friction coefficients need (at ``mu = 1000`` the term ``mu
      ||u_t||`` of eq. 44 makes the plain step crawl), then halves ``rho``;
      the sweeps go on from the current iterate (its residual need not fall
      monotonically).

    Returns ``(r, u, iterations, residual, history)``: the last iterate, or
    the best one if it has the lower residual, and the residual at each check.
    """
    n = q.shape[0]
    rho = paper_rho(W)
    W = np.ascontiguousarray(W)
    check_every = 1 if gauss_seidel else 10
    guard = _Safeguard(gauss_seidel, r)
    history = []
    # force scale of the problem: a solution is far below _BLOWUP times this
    r_ref = max(np.linalg.norm(r), np.linalg.norm(rho[:, None] * q), 1e-300)
    it = 0
    while it < max_iter:
        u = (W @ r.ravel()).reshape(n, 3) + q
        if it % check_every == 0:
            res = residual(r, u)
            history.append(res)
            if res <= tol:
                break
            # the normalised residual shrinks as |r| blows up, so size guards it too
            blown_up = not np.isfinite(res) or np.linalg.norm(r) > _BLOWUP * r_ref
            if guard.restart(r, res, blown_up, W):
                r = guard.best_r.copy()
                u = (W @ r.ravel()).reshape(n, 3) + q
        if gauss_seidel:
            r = np.array(r)
            _gauss_seidel_sweeps(W, q, mx, my, guard.omega * rho, r, 1, guard.stick_inverse)
        else:
            r = _project(r - guard.omega * rho[:, None] * _modified(u, mx, my), mx, my)
        it += 1
    u = (W @ r.ravel()).reshape(n, 3) + q
    res = residual(r, u)
    if res > guard.best_res:
        r, res = guard.best_r, guard.best_res
        u = (W @ r.ravel()).reshape(n, 3) + q
    history.append(res)
    return r, u, it, res, history


class _Safeguard:
    """The state of :func:`uzawa`'s safeguards: the best iterate and its residual, the
    step factor ``omega`` (halved on trouble), the residuals since the last change of the
    iteration and the contacts' stick inverses (n, 3, 3), empty until a Gauss-Seidel
    stall turns them on."""

    def __init__(self, gauss_seidel: bool, r: np.ndarray):
        self.gauss_seidel = gauss_seidel
        self.window = 10 * _STALL_CHECKS if gauss_seidel else _STALL_CHECKS
        self.best_r, self.best_res = r, np.inf
        self.omega = 1.0
        self.segment: list[float] = []
        self.stick_inverse = np.zeros((0, 3, 3))

    def restart(self, r: np.ndarray, res: float, blown_up: bool, W: np.ndarray) -> bool:
        """Record a check's residual ``res`` of ``r``; True when the iteration must restart
        from ``best_r`` (``omega`` then halved): blow-up, growth (Jacobi) or a stall."""
        if res < self.best_res and not blown_up:
            self.best_r, self.best_res = r.copy(), res
        self.segment.append(res)
        stalled = len(self.segment) > self.window and res > _STALL_RATIO * self.segment[-self.window - 1]
        grown = not self.gauss_seidel and res > _GROWTH * self.best_res
        if self.gauss_seidel and stalled and not blown_up:
            if self.stick_inverse.shape[0] == 0:
                self.stick_inverse = _stick_inverses(W, r.shape[0])
            else:
                self.omega *= 0.5
            self.segment = []
            return False
        if blown_up or grown or stalled:
            self.omega *= 0.5
            self.segment = []
            return True
        return False
