# cython: language_level=3, cdivision=True, initializedcheck=False
"""Compiled per-contact kernels of the contact layer (built at install, see setup.py):
the elliptic cone projection of :mod:`fe_contact.contact.friction`, the
Alart-Curnier function of :mod:`fe_contact.contact.alart_curnier` and the paper's
Gauss-Seidel Uzawa sweep of :mod:`fe_contact.contact.uzawa`.

Floating-point semantics are those of the numba kernels they replace (issue 32):
IEEE double, no fast-math, no contraction into fused multiply-adds (setup.py
passes ``-ffp-contract=off``), and ``cdivision``: a division by zero gives
``inf`` or ``nan`` as in numpy, never an exception.  Bounds and wrap-around
checks are off in each function only after its shapes have been checked on entry
(a ``ValueError`` otherwise), so that every index below is in range.
"""

cimport cython
from libc.math cimport fabs, hypot, sqrt

import numpy as np

ROOT_MAX_ITER = 100  # Newton passes of the cone projection's root search (at most 13 measured)
cdef int _ROOT_MAX_ITER = ROOT_MAX_ITER


cdef inline double _max(double a, double b) noexcept nogil:
    """Python's (and numba's) ``max(a, b)``: ``a`` unless ``b > a``, so that
    signed zeros and NaN come out as they did."""
    return b if b > a else a


cdef void _project_one(double a0, double a1, double a2, double mux, double muy, double* r) noexcept nogil:
    """The projection of one contact's ``(a0, a1, a2)`` into ``r[0:3]`` (see
    :func:`_project_kernel`)."""
    cdef double scale, s, tn, t1, t2, sup, c1, c2, m2x, m2y, ix, iy, ex, ey, cx, cy
    cdef double delta, jx, jy, gx, gy, phi, step, new, tb, dx, dy
    cdef int it
    cdef bint done
    r[0] = 0.0
    r[1] = 0.0
    r[2] = 0.0
    scale = _max(_max(fabs(a0), fabs(a1)), fabs(a2))
    s = scale if scale > 0.0 else 1.0
    tn, t1, t2 = a0 / s, a1 / s, a2 / s
    sup = hypot(mux * t1, muy * t2)  # ||M tau_t||
    c1 = 0.0 if t1 == 0.0 else t1 / mux  # M^-1 tau_t
    c2 = 0.0 if t2 == 0.0 else t2 / muy
    if hypot(c1, c2) <= tn:  # inside
        r[0], r[1], r[2] = a0, a1, a2
        return
    if tn + sup <= 0.0:  # polar
        return
    if sup == 0.0:  # outside both with tau_n > 0: onto the axis
        r[0] = a0
        return
    m2x, m2y = mux * mux, muy * muy
    ix, iy = 1.0 / (1.0 + m2x), 1.0 / (1.0 + m2y)
    ex, ey = t1 * mux * ix, t2 * muy * iy
    cx, cy = m2x * tn * ix, m2y * tn * iy
    delta = _max(_max(-tn, 0.0), _max(fabs(ex) - cx, fabs(ey) - cy))
    # a zero e_i contributes nothing, whatever c_i; c_i = 1 keeps its term finite
    if ex == 0.0:
        cx = 1.0
    if ey == 0.0:
        cy = 1.0
    for it in range(_ROOT_MAX_ITER):
        jx, jy = 1.0 / (delta + cx), 1.0 / (delta + cy)
        gx, gy = ex * jx, ey * jy
        gx, gy = gx * gx, gy * gy
        phi = gx + gy
        # Newton step (1 - h) / h' with h = phi^(-1/2), h' = h^3 sum_i g_i^2 / (delta + c_i)
        step = phi * (sqrt(phi) - 1.0) / (gx * jx + gy * jy)
        # rounding can make the last steps <= 0 or NaN: the root is reached
        if not step > 0.0:
            step = 0.0
        new = delta + step
        done = step <= 4e-16 * new
        delta = new
        if done:
            break
    tb = tn + delta
    dx, dy = delta + m2x * tb, delta + m2y * tb
    # d == 0 only if delta and mu^2 t both underflow: |r_tk| is below rounding
    r[0] = tb * s
    r[1] = a1 * (m2x * tb / dx if dx > 0.0 else 0.0)
    r[2] = a2 * (m2y * tb / dy if dy > 0.0 else 0.0)


@cython.boundscheck(False)
@cython.wraparound(False)
def _project_kernel(const double[:, ::1] a, const double[::1] mx, const double[::1] my):
    """The projection of each row of ``a`` (n, 3) onto the elliptic cone of
    coefficients ``mx``, ``my`` (n,), one contact at a time; returns ``r`` (n, 3).

    Each row is normalised (``max |t_i| = 1``, a zero row stays 0 and is
    polar).  Inside the cone it is kept, in the polar cone it goes to 0, with
    no friction-weighted tangential part to the normal axis, and otherwise
    onto the boundary: ``r = (t, tau_tx mu_x^2 t / d_x, tau_ty mu_y^2 t /
    d_y)`` with ``d_i = (1 + mu_i^2) t - tau_n``, where ``t`` solves ``sum_i
    (tau_ti mu_i / d_i)^2 = 1``.  The unknown is ``delta = t - tau_n``, so
    that ``d_i = delta + mu_i^2 t`` keeps full relative precision for narrow
    cones (``t - tau_n`` computed from ``t`` is pure rounding once ``mu <
    1e-8``).  With ``e_i = tau_ti mu_i / (1 + mu_i^2)`` and ``c_i = mu_i^2
    tau_n / (1 + mu_i^2)`` the equation reads ``phi(delta) = sum_i e_i^2 /
    (delta + c_i)^2 = 1`` (the secular equation of a point-to-ellipse
    distance).  ``h = phi^(-1/2)`` is a weighted power mean with exponent -2
    of the ``delta + c_i`` > 0, hence increasing and concave in ``delta``; it
    is <= 1 at ``lo = max_i(|e_i| - c_i)`` (one term alone reaches 1 there),
    so Newton on ``h = 1`` from ``lo`` increases monotonically to the root,
    with no overshoot to guard against.  Measured: at most 8 passes for
    ``mu_x / mu_y = 6``, 13 for 1e4.

    Division by a zero coefficient gives ``inf`` (``cdivision``): a tangential
    component along an axis without friction puts the point outside the cone,
    and ``inf`` for a tiny ``mu`` is the right answer too.
    """
    cdef Py_ssize_t n = a.shape[0], k
    if a.shape[1] != 3 or mx.shape[0] != n or my.shape[0] != n:
        raise ValueError(f"_project_kernel: a must be (n, 3) and mx, my (n,), got ({n}, {a.shape[1]}), "
                         f"({mx.shape[0]},), ({my.shape[0]},)")
    out = np.zeros((n, 3))
    cdef double[:, ::1] r = out
    with nogil:
        for k in range(n):
            _project_one(a[k, 0], a[k, 1], a[k, 2], mx[k], my[k], &r[k, 0])
    return out


@cython.boundscheck(False)
@cython.wraparound(False)
def _ac_kernel(const double[:, :] s, const double[:, :] u, const double[:] mu, const double[:, :] rho,
               const unsigned char[:, :] fixed, double[:, :, ::1] P, double[:, :, ::1] Q):
    """``F`` (n, 3) of :func:`fe_contact.contact.alart_curnier.alart_curnier` for
    scaled forces ``s`` and displacements ``u`` (n, 3), coefficients ``mu`` (n,),
    ``rho`` (n, 2) and the pinned components ``fixed`` (n, 3, as uint8), and its
    Jacobian blocks into ``P``, ``Q`` (zeroed, shape (n, 3, 3)) unless they have no
    rows.

    Per contact, with ``p = s_n - rho_n u_n``, ``R = mu max(p, 0)``, ``z = s_t -
    rho_t u_t``; the Jacobian is ``blockdiag(P) + Q W_s``:

    * normal row, active (p > 0): ``rho_n W_n`` (P = 0, Q = rho_n e_n);
      inactive: ``e_n`` (P = e_n, Q = 0);
    * tangent rows, stick (|z| <= R, R > 0): ``rho_t W_t`` (P = 0, Q = rho_t [0 I]);
      slide: ``E_t - zhat dR^T - R/|z| (I - zhat zhat^T)(E_t - rho_t W_t)`` with
      ``dR = mu (e_n - rho_n W_n)`` when active, else 0;
    * components pinned to zero: ``F = s``, row ``e_i``.
    """
    cdef Py_ssize_t n = s.shape[0], c, i, j
    cdef bint jac = P.shape[0] > 0
    if (s.shape[1] != 3 or u.shape[0] != n or u.shape[1] != 3 or mu.shape[0] != n or rho.shape[0] != n
            or rho.shape[1] != 2 or fixed.shape[0] != n or fixed.shape[1] != 3
            or (jac and (P.shape[0] != n or Q.shape[0] != n or P.shape[1] != 3 or P.shape[2] != 3
                         or Q.shape[1] != 3 or Q.shape[2] != 3))):
        raise ValueError("_ac_kernel: s, u, fixed must be (n, 3), mu (n,), rho (n, 2), P and Q (n, 3, 3) or empty")
    out = np.empty((n, 3))
    cdef double[:, ::1] F = out
    cdef double rn, r, p, R, z1, z2, zn
    cdef double h[2]
    cdef bint active, stick
    with nogil:
        for c in range(n):
            rn, r = rho[c, 0], rho[c, 1]
            p = s[c, 0] - rn * u[c, 0]
            active = p > 0.0
            R = mu[c] * p if active else 0.0
            z1 = s[c, 1] - r * u[c, 1]
            z2 = s[c, 2] - r * u[c, 2]
            zn = sqrt(z1 * z1 + z2 * z2)
            stick = zn <= R and R > 0.0
            if zn > 0.0:
                h[0], h[1] = z1 / zn, z2 / zn
            else:
                h[0], h[1] = 0.0, 0.0
            F[c, 0] = rn * u[c, 0] if active else s[c, 0]
            if stick:
                F[c, 1], F[c, 2] = r * u[c, 1], r * u[c, 2]
            else:
                F[c, 1], F[c, 2] = s[c, 1] - R * h[0], s[c, 2] - R * h[1]
            if jac:
                _ac_jacobian(P, Q, c, active, stick, rn, r, R, zn, mu[c], h)
            for i in range(3):
                if fixed[c, i]:
                    F[c, i] = s[c, i]
                    if jac:
                        for j in range(3):
                            P[c, i, j] = 1.0 if i == j else 0.0
                            Q[c, i, j] = 0.0
    return out


@cython.boundscheck(False)
@cython.wraparound(False)
cdef inline void _ac_jacobian(double[:, :, ::1] P, double[:, :, ::1] Q, Py_ssize_t c, bint active, bint stick,
                              double rn, double r, double R, double zn, double mu_c, double* h) noexcept nogil:
    """The Jacobian blocks ``P[c]``, ``Q[c]`` of contact ``c`` (zeroed on entry) as listed in
    :func:`_ac_kernel`: ``rn``, ``r`` its normal and tangential ``rho``, ``R = mu max(p, 0)``,
    ``zn = |z|`` and ``h`` (2,) = ``z / |z|`` (0 at ``z = 0``)."""
    cdef double coef, m_act, proj
    cdef Py_ssize_t i, j
    if active:
        Q[c, 0, 0] = rn
    else:
        P[c, 0, 0] = 1.0
    if stick:
        Q[c, 1, 1] = r
        Q[c, 2, 2] = r
    else:
        coef = R / zn if zn > 0.0 else 0.0
        m_act = mu_c if active else 0.0
        for i in range(2):
            P[c, 1 + i, 0] = -m_act * h[i]
            Q[c, 1 + i, 0] = m_act * rn * h[i]
            for j in range(2):
                proj = (1.0 if i == j else 0.0) - h[i] * h[j]
                P[c, 1 + i, 1 + j] = (1.0 if i == j else 0.0) - coef * proj
                Q[c, 1 + i, 1 + j] = coef * r * proj


@cython.boundscheck(False)
@cython.wraparound(False)
def _gauss_seidel_sweeps(const double[:, ::1] W, const double[:, :] q, const double[:] mx, const double[:] my,
                         const double[:] rho, double[:, ::1] r, int sweeps, const double[:, :, :] stick_inverse):
    """``sweeps`` Gauss-Seidel sweeps of eq. 44 over the contacts, in place on ``r`` (n, 3).

    ``W`` (3n, 3n) and ``q`` (n, 3) of ``u = W r + q``, the coefficients ``mx``,
    ``my`` and steps ``rho`` (n,).  With ``stick_inverse`` (the inverses of the
    contacts' 3x3 diagonal blocks of ``W``, shape (n, 3, 3); no rows: not used) a
    contact first tries sticking: ``r_c = -W_cc^-1 (u_c - W_cc r_c)``, the reaction
    that cancels its own displacement, is its exact local solution whenever it
    lies in ``K_mu``; otherwise it takes the step of eq. 44.
    """
    cdef Py_ssize_t n = q.shape[0], c, i, j, sweep
    cdef bint stick = stick_inverse.shape[0] > 0
    if (q.shape[1] != 3 or r.shape[0] != n or r.shape[1] != 3 or W.shape[0] != 3 * n or W.shape[1] != 3 * n
            or mx.shape[0] != n or my.shape[0] != n or rho.shape[0] != n
            or (stick and (stick_inverse.shape[0] != n or stick_inverse.shape[1] != 3
                           or stick_inverse.shape[2] != 3))):
        raise ValueError("_gauss_seidel_sweeps: W must be (3n, 3n), q and r (n, 3), mx, my, rho (n,), "
                         "stick_inverse (n, 3, 3) or empty")
    cdef double u0, u1, u2, rj, f0, f1, f2, s0, s1, s2, c1, c2, rc
    cdef double* rf = &r[0, 0] if n > 0 else NULL  # r (C-contiguous) as its 3n entries
    cdef double p[3]
    with nogil:
        for sweep in range(sweeps):
            for c in range(n):
                u0, u1, u2 = q[c, 0], q[c, 1], q[c, 2]
                for j in range(3 * n):
                    rj = rf[j]
                    u0 += W[3 * c, j] * rj
                    u1 += W[3 * c + 1, j] * rj
                    u2 += W[3 * c + 2, j] * rj
                if stick:
                    # displacement with this contact's own reaction taken out
                    f0, f1, f2 = u0, u1, u2
                    for i in range(3):
                        rj = r[c, i]
                        f0 -= W[3 * c, 3 * c + i] * rj
                        f1 -= W[3 * c + 1, 3 * c + i] * rj
                        f2 -= W[3 * c + 2, 3 * c + i] * rj
                    s0 = -(stick_inverse[c, 0, 0] * f0 + stick_inverse[c, 0, 1] * f1 + stick_inverse[c, 0, 2] * f2)
                    s1 = -(stick_inverse[c, 1, 0] * f0 + stick_inverse[c, 1, 1] * f1 + stick_inverse[c, 1, 2] * f2)
                    s2 = -(stick_inverse[c, 2, 0] * f0 + stick_inverse[c, 2, 1] * f1 + stick_inverse[c, 2, 2] * f2)
                    c1 = 0.0 if s1 == 0.0 else s1 / mx[c]
                    c2 = 0.0 if s2 == 0.0 else s2 / my[c]
                    if s0 >= 0.0 and hypot(c1, c2) <= s0:
                        r[c, 0], r[c, 1], r[c, 2] = s0, s1, s2
                        continue
                rc = rho[c]
                _project_one(r[c, 0] - rc * (u0 + hypot(mx[c] * u1, my[c] * u2)), r[c, 1] - rc * u1,
                             r[c, 2] - rc * u2, mx[c], my[c], p)
                r[c, 0], r[c, 1], r[c, 2] = p[0], p[1], p[2]


@cython.boundscheck(False)
@cython.wraparound(False)
def _newton_matrix_kernel(const double[:, :, ::1] P, const double[:, :, ::1] Q, const double[:, ::1] W,
                          const double[::1] d, double[:, ::1] J):
    """The Newton matrix ``J = blockdiag(P) + blockdiag(Q) D W D`` (3 n, 3 n) into ``J``, from
    ``P``, ``Q`` (n, 3, 3), ``W`` (3 n, 3 n) and ``d`` (3 n,) (``D = diag(d)``): row ``3 c + i``
    is ``(sum_j Q[c, i, j] d[3 c + j] W[3 c + j, :]) * d``, then ``P[c]`` added to its
    diagonal block.  The products and sums in the order of ``numpy.einsum("cij,cjm->cim")``
    then ``*= d`` (:func:`fe_contact.contact.alart_curnier.newton_matrix`), without its
    temporaries: one pass over ``W`` instead of four."""
    cdef Py_ssize_t n = P.shape[0], m = 3 * P.shape[0], c, i, j, k, row
    cdef double q0, q1, q2
    if Q.shape[0] != n or W.shape[0] != m or W.shape[1] != m or d.shape[0] != m or J.shape[0] != m or J.shape[1] != m:
        raise ValueError("_newton_matrix_kernel: P, Q (n, 3, 3), W and J (3 n, 3 n), d (3 n,)")
    with nogil:
        for c in range(n):
            for i in range(3):
                row = 3 * c + i
                q0 = Q[c, i, 0] * d[3 * c]
                q1 = Q[c, i, 1] * d[3 * c + 1]
                q2 = Q[c, i, 2] * d[3 * c + 2]
                for k in range(m):
                    J[row, k] = (q0 * W[3 * c, k] + q1 * W[3 * c + 1, k] + q2 * W[3 * c + 2, k]) * d[k]
                for j in range(3):
                    J[row, 3 * c + j] += P[c, i, j]
