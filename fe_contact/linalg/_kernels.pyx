# cython: language_level=3, cdivision=True, initializedcheck=False
"""Compiled kernel of the linear-algebra layer (built at install, see setup.py): the
extend-add of :mod:`fe_contact.linalg.cholesky`'s multifrontal factorisation.

Floating-point semantics are those of the numba kernel it replaces (issue 32): IEEE
double, no fast-math, no fused multiply-add (setup.py passes ``-ffp-contract=off``).
Bounds and wrap-around checks are off only after the indices have been checked on
entry (a ``ValueError`` otherwise).
"""

cimport cython
from libc.stdint cimport int64_t


@cython.boundscheck(False)
@cython.wraparound(False)
def _extend_add(double[::1, :] panel, double[::1, :] corner, const double[:, :] U, const int64_t[:] rel):
    """Add a child's update ``U`` (its lower triangle; the upper one is not
    computed) into its parent's front: entry ``(i, j)``, ``i >= j``, goes to
    front position ``(rel[i], rel[j])``, which is in the parent's ``panel``
    (its pivot columns, ``(p + q, p)``) if ``rel[j] < p``, else in its
    ``corner`` (the boundary block, ``(q, q)``).  ``panel`` and ``corner``
    Fortran-ordered, ``rel`` (m,) strictly increasing, ``U`` at least (m, m).

    One pass over the update, a column at a time.  The numpy equivalent, a
    gather-add-scatter per run of consecutive positions, took a third of the
    factorisation at 2.3e5 dofs (21.7 of 68 s).
    """
    cdef Py_ssize_t p = panel.shape[1], q = corner.shape[0], m = rel.shape[0], i, j, col
    # the indices below are in range: 0 <= rel[0] < ... < rel[m - 1] < p + q
    if panel.shape[0] != p + q or corner.shape[1] != q or U.shape[0] < m or U.shape[1] < m:
        raise ValueError(f"_extend_add: panel ({panel.shape[0]}, {p}), corner ({q}, {corner.shape[1]}) "
                         f"and U ({U.shape[0]}, {U.shape[1]}) do not fit {m} positions")
    for i in range(m):
        if rel[i] < (rel[i - 1] + 1 if i else 0) or rel[i] >= p + q:
            raise ValueError(f"_extend_add: rel must increase strictly within [0, {p + q}), got {rel[i]} at {i}")
    with nogil:
        for j in range(m):
            col = rel[j]
            if col < p:
                for i in range(j, m):
                    panel[rel[i], col] += U[i, j]
            else:
                for i in range(j, m):  # rel is increasing: rel[i] >= col >= p
                    corner[rel[i] - p, col - p] += U[i, j]
