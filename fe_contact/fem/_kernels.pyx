# cython: language_level=3, cdivision=True, initializedcheck=False
"""Compiled kernel of the finite-element layer (built at install, see setup.py): the
St Venant-Kirchhoff hex8 internal force of :func:`fe_contact.fem.elasticity.internal_force`,
every Newton iteration's assembly.

Floating-point semantics as in the other compiled kernels: IEEE double, no fast-math,
no fused multiply-add (setup.py passes ``-ffp-contract=off``).  Bounds and wrap-around
checks are off only after the shapes and the node numbers have been checked on entry
(a ``ValueError`` otherwise).
"""

cimport cython
from libc.stdint cimport int64_t


@cython.boundscheck(False)
@cython.wraparound(False)
def stvk_forces(const double[:, :, ::1] grad, const double[:, ::1] dvol, const int64_t[:, ::1] elements,
                const double[:, ::1] U, double lam, double mu, double[::1] f):
    """Add the St Venant-Kirchhoff internal force ``f_a = sum_q dV P g_a`` of every
    element to ``f`` (3 n_nodes,), N, node-major, element by element in order, and
    return the smallest ``det F`` over the Gauss points.

    At each Gauss point (total Lagrangian, Bathe ch. 6; the paper's eq. 2-4):
    ``H_iJ = sum_a U_ai g_aJ`` (``g_a = dN_a/dX``, ``grad`` (n_elems, 8, 3 n_qp) with
    ``g_aJ`` of point ``q`` at ``[e, a, 3 q + J]`` (``ElementGeometry.grad_rows``), 1/m), ``E = (H + H^T + H^T H) / 2``, ``S = lam tr(E) I + 2 mu E`` (Pa),
    ``P = (I + H) S``; ``dvol`` (n_elems, n_qp), m^3; ``elements`` (n_elems, 8);
    ``U`` (n_nodes, 3), m.  One pass over the points, nothing stored per point:
    the numpy form of the same sums made a dozen arrays of 9 x n_points.
    """
    cdef Py_ssize_t n_elems = grad.shape[0], n_qp = dvol.shape[1], n_nodes = U.shape[0]
    cdef Py_ssize_t e, q, a, i, j, k
    cdef int64_t node
    cdef double u[8][3]
    cdef double fe[8][3]
    cdef double H[3][3]
    cdef double P[3][3]
    cdef double s, det, min_det = float("inf")
    if (grad.shape[1] != 8 or grad.shape[2] != 3 * n_qp or dvol.shape[0] != n_elems
            or elements.shape[0] != n_elems or elements.shape[1] != 8 or U.shape[1] != 3
            or f.shape[0] != 3 * n_nodes):
        raise ValueError(f"stvk_forces: grad {tuple(grad.shape)}, dvol {tuple(dvol.shape)}, elements "
                         f"{tuple(elements.shape)}, U {tuple(U.shape)} and f ({f.shape[0]},) do not fit")
    for e in range(n_elems):
        for a in range(8):
            if elements[e, a] < 0 or elements[e, a] >= n_nodes:
                raise ValueError(f"stvk_forces: element {e} names node {elements[e, a]} of {n_nodes}")
    with nogil:
        for e in range(n_elems):
            for a in range(8):
                node = elements[e, a]
                for i in range(3):
                    u[a][i] = U[node, i]
                    fe[a][i] = 0.0
            for q in range(n_qp):
                for i in range(3):
                    for j in range(3):
                        s = 0.0
                        for a in range(8):
                            s = s + u[a][i] * grad[e, a, 3 * q + j]
                        H[i][j] = s
                det = _stvk_piola(H, lam, mu, dvol[e, q], P)
                for a in range(8):
                    for i in range(3):
                        fe[a][i] = fe[a][i] + (P[i][0] * grad[e, a, 3 * q] + P[i][1] * grad[e, a, 3 * q + 1]
                                               + P[i][2] * grad[e, a, 3 * q + 2])
                if det < min_det or det != det:  # a NaN stays, as in numpy's min
                    min_det = det
            for a in range(8):
                node = elements[e, a]
                for i in range(3):
                    f[3 * node + i] = f[3 * node + i] + fe[a][i]
    return min_det


cdef inline double _stvk_piola(double H[3][3], double lam, double mu, double w, double P[3][3]) noexcept nogil:
    """At one Gauss point of displacement gradient ``H`` (3, 3): ``P = w (I + H) S`` into ``P``
    (N m, ``w`` the point's volume, m^3), with ``E = (H + H^T + H^T H) / 2`` and
    ``S = lam tr(E) I + 2 mu E`` (Pa); returns ``det F = det(I + H)``."""
    cdef double E[3][3]
    cdef double S[3][3]
    cdef double s, tr
    cdef Py_ssize_t i, j, k
    for i in range(3):
        for j in range(3):
            E[i][j] = 0.5 * (H[i][j] + H[j][i] + H[0][i] * H[0][j] + H[1][i] * H[1][j]
                             + H[2][i] * H[2][j])
    tr = E[0][0] + E[1][1] + E[2][2]
    for i in range(3):
        for j in range(3):
            S[i][j] = 2.0 * mu * E[i][j]
        S[i][i] = S[i][i] + lam * tr
    for i in range(3):
        for j in range(3):
            s = S[i][j]
            for k in range(3):
                s = s + H[i][k] * S[k][j]
            P[i][j] = w * s
    return ((1.0 + H[0][0]) * ((1.0 + H[1][1]) * (1.0 + H[2][2]) - H[1][2] * H[2][1])
            - H[0][1] * (H[1][0] * (1.0 + H[2][2]) - H[1][2] * H[2][0])
            + H[0][2] * (H[1][0] * H[2][1] - (1.0 + H[1][1]) * H[2][0]))
