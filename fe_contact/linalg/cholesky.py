"""Multifrontal sparse Cholesky factorisation of the free-dof stiffness with the
contact dofs eliminated last.

The free dofs are ordered by geometric nested dissection of the interior
(:func:`fe_contact.fem.mesh.nested_dissection_parts`) and the contact dofs last.
Each part of the ordering is a *supernode*: its columns of the factor are kept
as one dense block over the part and the later dofs they couple to (its
*boundary*), and the elimination of the part is a dense Cholesky factorisation,
triangular solve and rank update of its *frontal matrix* (BLAS 3 through
LAPACK).  The update of a part is added into the frontal matrix of its parent
(the part that holds its first boundary dof), so only the update matrices of
parts whose parent is not yet eliminated are alive at once.

Because the contact dofs come last, the frontal matrix of the last part is the
Schur complement ``S = K_cc - K_ci K_ii^-1 K_ic`` of the interior onto the
contact dofs, and the contact block of ``K_ff^-1`` — the flexibility matrix of
the paper (sect. 8) — is ``S^-1``: no solve with one right-hand side per
contact dof is needed.

The structure (ordering, boundaries, assembly maps) depends only on the mesh
and is computed once per model (:func:`supernodal_structure`); a tangent is
factorised with :func:`factorise`.  The symbolic boundaries follow from the
sparsity pattern for any partition of the ordering into consecutive parts, so
the result is exact for every ordering; nested dissection only keeps the fill
small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import blas, lapack

from ._kernels import _extend_add  # compiled: one pass over a child's update (_kernels.pyx)

__all__ = ["SupernodalStructure", "SupernodalFactor", "NotPositiveDefinite", "supernodal_structure", "factorise"]


class NotPositiveDefinite(np.linalg.LinAlgError):
    """A pivot block of the factorisation is not positive definite."""


@dataclass(frozen=True)
class SupernodalStructure:
    """Symbolic factorisation of the free-dof block of one sparsity pattern.

    Attributes
    ----------
    perm : ndarray of int64, shape (n_free,)
        Positions in the free-dof vector in elimination order; the last
        ``n_root`` are the contact dofs in the order given to
        :func:`supernodal_structure`.
    starts : ndarray of int64, shape (n_parts + 1,)
        Part ``s`` eliminates ``perm[starts[s]:starts[s + 1]]``.
    boundary : tuple of ndarray of int64
        Per part, the elimination indices after the part that its factor
        columns couple to (sorted).
    parent : ndarray of int64, shape (n_parts,)
        Part receiving each part's update (-1 for the last part).
    relative : tuple of ndarray of int64
        Per part, the positions of its boundary inside its parent's front.
    source, target : tuple of ndarray of int64
        Per part, the positions in the matrix data array (CSR of the full
        pattern) of the entries the part assembles, and their flat positions
        (Fortran order) in the pivot columns of its frontal matrix, shape
        ``(p + q, p)`` for ``p`` dofs and ``q`` boundary dofs (lower triangle).
    nnz : int
        Entries of the factor ``L``, diagonal blocks counted whole.
    max_front : int
        Order of the largest frontal matrix.
    flops : float
        Floating-point operations of one numerical factorisation, the
        inversion of the last part (flexibility matrix) not included.
    """

    perm: np.ndarray
    starts: np.ndarray
    boundary: tuple
    parent: np.ndarray
    relative: tuple
    source: tuple
    target: tuple
    nnz: int
    max_front: int
    flops: float

    @property
    def n_parts(self) -> int:
        return int(self.starts.size - 1)

    @property
    def n_root(self) -> int:
        """Number of dofs of the last part (the contact dofs)."""
        return int(self.starts[-1] - self.starts[-2])


def _entries_by_part(indptr, indices, elim: np.ndarray, starts: np.ndarray):
    """The entries ``(i, j)`` of ``K`` with both dofs free and ``j`` eliminated
    no earlier than ``i``: the part of ``i`` assembles them into column ``i``
    of its front, row ``j``.

    Returns their positions in ``K.data``, the elimination positions of ``i``
    (sorted) and of ``j``, and where each part's entries begin
    (``len(starts)``,).
    """
    rows = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))
    er, ec = elim[rows], elim[indices]
    keep = (er >= 0) & (ec >= er)
    pos = np.flatnonzero(keep)
    er, ec = er[keep], ec[keep]
    by_row = np.argsort(er, kind="stable")
    pos, er, ec = pos[by_row], er[by_row], ec[by_row]
    return pos, er, ec, np.searchsorted(er, starts)


def supernodal_structure(indptr, indices, free: np.ndarray, parts, root: np.ndarray) -> SupernodalStructure:
    """Symbolic multifrontal factorisation of ``K[free][:, free]``.

    Parameters
    ----------
    indptr, indices : ndarray of int
        CSR structure of the full symmetric ``K`` (sorted or not).
    free : ndarray of int64, shape (n_free,)
        Sorted free dofs.
    parts : sequence of ndarray of int64
        Interior free dofs (global ids) by part, in elimination order; with
        ``root`` they must cover ``free`` exactly once.
    root : ndarray of int64
        Dofs eliminated last as one part (the contact dofs), in the order the
        Schur complement onto them is wanted.

    Returns
    -------
    SupernodalStructure

    Raises
    ------
    ValueError
        If the parts and the root do not cover the free dofs exactly once.
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    order, elim, starts = _elimination_order(indptr.size - 1, free, parts, root)
    pos, er, ec, bounds = _entries_by_part(indptr, indices, elim, starts)
    boundary, fronts, source, target, parent, nnz, flops = _symbolic_parts(starts, pos, er, ec, bounds)
    relative = tuple(
        np.searchsorted(fronts[parent[s]], boundary[s]) if parent[s] >= 0 else np.zeros(0, dtype=np.int64)
        for s in range(starts.size - 1)
    )
    free_position = np.searchsorted(free, order)
    return SupernodalStructure(
        perm=free_position, starts=starts, boundary=tuple(boundary), parent=parent, relative=relative,
        source=tuple(source), target=tuple(target), nnz=int(nnz), max_front=max(f.size for f in fronts),
        flops=float(flops),
    )


def _elimination_order(n_dofs: int, free: np.ndarray, parts, root):
    """The elimination order of the free dofs: the parts' dofs, then the root's.

    Returns ``order`` (n_free,) the dofs in elimination order, ``elim`` (n_dofs,) each
    dof's elimination position (-1 for a fixed dof) and ``starts`` (n_parts + 1,) where
    each part (the root the last) begins; raises ValueError if they do not cover ``free``
    exactly once.
    """
    parts = [np.asarray(p, dtype=np.int64) for p in parts if len(p)] + [np.asarray(root, dtype=np.int64)]
    order = np.concatenate(parts)
    if order.size != free.size or not np.array_equal(np.sort(order), free):
        raise ValueError(
            f"parts and root must cover the {free.size} free dofs exactly once, got {order.size} dofs"
        )
    elim = np.full(n_dofs, -1, dtype=np.int64)
    elim[order] = np.arange(order.size)
    starts = np.zeros(len(parts) + 1, dtype=np.int64)
    np.cumsum([p.size for p in parts], out=starts[1:])
    return order, elim, starts


def _symbolic_parts(starts: np.ndarray, pos, er, ec, bounds):
    """Per part, in elimination order: its boundary ``B`` (the later dofs its own entries
    and its children's boundaries couple to), its front (its dofs then ``B``), the
    assembly maps ``source`` / ``target`` and its parent (the part of ``B[0]``), with the
    factor's entries ``nnz`` and flops ``p^3/3 + p^2 q + p q^2`` summed over the parts
    (``p`` dofs, ``q`` boundary dofs). A loop over parts (about 2 n_nodes / 64), not dofs."""
    n_parts = starts.size - 1
    boundary, fronts, source, target = [], [], [], []
    parent = np.full(n_parts, -1, dtype=np.int64)
    children: list[list[int]] = [[] for _ in range(n_parts)]
    nnz, flops = 0, 0.0
    for s in range(n_parts):
        a, b = starts[s], starts[s + 1]
        lo, hi = bounds[s], bounds[s + 1]
        cols = ec[lo:hi]
        coupled = [cols[cols >= b]] + [boundary[c][boundary[c] >= b] for c in children[s]]
        B = np.unique(np.concatenate(coupled))
        front = np.concatenate([np.arange(a, b), B])
        n_front = front.size
        target.append(np.searchsorted(front, cols) + (er[lo:hi] - a) * n_front)
        source.append(pos[lo:hi])
        boundary.append(B)
        fronts.append(front)
        if B.size:
            parent[s] = np.searchsorted(starts, B[0], side="right") - 1
            children[parent[s]].append(s)
        p, q = int(b - a), int(B.size)
        nnz += p * (p + 1) // 2 + p * q
        flops += p**3 / 3.0 + p * p * q + p * q * q
    return boundary, fronts, source, target, parent, nnz, flops


DENSE_SOLVE_ORDER = 600
"""At most this many free dofs (a planning mesh: 294 at 6 x 6 x 2), :meth:`SupernodalFactor.forward`
and :meth:`~SupernodalFactor.backward` substitute with the factor's blocks gathered into one dense
triangle (elimination order, built once per factor, 2.9 MB at this order), one BLAS call each way,
instead of a part at a time: the loop over the parts (a triangular solve, a product and an indexed
update each) costs more in calls than in arithmetic at this size.  The same ``L``; the sums of a
substitution in another order (rounding)."""


class SupernodalFactor:
    """Numerical factor ``K_ff = L L^T`` (elimination order) and the Schur
    complement onto the contact dofs, from :func:`factorise`."""

    def __init__(self, structure: SupernodalStructure, diagonal: list, below: list):
        self.structure = structure
        self._diagonal = diagonal  # per part: lower Cholesky factor of its pivot block (p, p), Fortran
        self._below = below  # per part: the factor rows of its boundary (q, p), Fortran
        self._dense = None  # the whole L, dense (n_free <= DENSE_SOLVE_ORDER), built at the first solve

    def _dense_factor(self) -> np.ndarray | None:
        """``L`` (n_free, n_free), lower, Fortran, in elimination order, or None above
        :data:`DENSE_SOLVE_ORDER`."""
        st = self.structure
        if self._dense is None and st.perm.size <= DENSE_SOLVE_ORDER:
            L = np.zeros((st.perm.size,) * 2, order="F")
            for s in range(st.n_parts):  # a few parts (4 on a planning mesh), once per factor
                a, b = st.starts[s], st.starts[s + 1]
                L[a:b, a:b] = self._diagonal[s]  # dpotrf's lower factor, its upper triangle zeroed
                L[st.boundary[s], a:b] = self._below[s]
            self._dense = L
        return self._dense

    @property
    def nnz(self) -> int:
        return self.structure.nnz

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``K_ff^-1 rhs`` for one right-hand side (n_free,) or several (n_free, k)."""
        rhs = np.asarray(rhs, dtype=float)
        return self.backward(self.forward(rhs)).reshape(rhs.shape)

    def forward(self, rhs: np.ndarray) -> np.ndarray:
        """``y`` with ``L y = rhs`` (rhs (n_free,) or (n_free, k), free-dof
        order), in elimination order, shape (n_free, k).  The root (contact)
        block is ``y[-n_root:]``; a right-hand side nonzero only on the contact
        dofs changes nothing else (:meth:`root_forward`)."""
        st = self.structure
        rhs = np.asarray(rhs, dtype=float)
        x = rhs[st.perm].reshape(rhs.shape[0], -1)
        L = self._dense_factor()
        if L is not None:
            return _triangular_solve(L, x)
        starts = st.starts
        for s in range(st.n_parts):  # L y = b
            a, b = starts[s], starts[s + 1]
            y = _triangular_solve(self._diagonal[s], x[a:b])
            x[a:b] = y
            if st.boundary[s].size:
                x[st.boundary[s]] -= self._below[s] @ y
        return x

    def backward(self, y: np.ndarray) -> np.ndarray:
        """``x`` with ``L^T x = y`` for ``y`` from :meth:`forward` (overwritten),
        in free-dof order, shape (n_free, k)."""
        st = self.structure
        x, starts = y, st.starts
        L = self._dense_factor()
        if L is not None:
            x = _triangular_solve(L, x, transposed=True)
        else:
            for s in range(st.n_parts - 1, -1, -1):  # L^T x = y
                a, b = starts[s], starts[s + 1]
                y = x[a:b]
                if st.boundary[s].size:
                    y = y - self._below[s].T @ x[st.boundary[s]]
                x[a:b] = _triangular_solve(self._diagonal[s], y, transposed=True)
        out = np.empty_like(x)
        out[st.perm] = x
        return out

    def root_forward(self, b: np.ndarray) -> np.ndarray:
        """``L_root^-1 b`` (n_root,) or (n_root, k): the root block of :meth:`forward` of
        right-hand sides ``b`` on the contact dofs (root order) and 0 elsewhere."""
        b = np.asarray(b, dtype=float)
        return _triangular_solve(self._diagonal[-1], b.reshape(b.shape[0], -1)).reshape(b.shape)

    def root_backward(self, y: np.ndarray) -> np.ndarray:
        """The contact dofs (root order) of :meth:`backward`: ``L_root^-T
        y_root``, the root block being eliminated last."""
        n_root = self.structure.n_root
        return _triangular_solve(self._diagonal[-1], y[-n_root:], transposed=True)

    def root_inverse(self) -> np.ndarray:
        """``S^-1``, the contact block of ``K_ff^-1`` (n_root, n_root), symmetric,
        C-contiguous, in the root order of :func:`supernodal_structure`."""
        G, info = lapack.dpotri(self._diagonal[-1], lower=1)
        if info != 0:
            raise NotPositiveDefinite(f"inverse of the contact Schur complement failed (dpotri info {info})")
        # mirror the lower triangle, a block of rows at a time (no n^2 index arrays)
        n, blk = G.shape[0], 512
        for i in range(0, n, blk):
            D = G[i:i + blk, i:i + blk]
            D[...] = np.tril(D) + np.tril(D, -1).T
            G[i:i + blk, i + blk:] = G[i + blk:, i:i + blk].T
        # LAPACK's result is Fortran-ordered; the same (exactly symmetric) matrix
        # in C order is its transpose, a view.  Consumers reshape rows into
        # contact blocks, (n, 3, n_root); on the Fortran layout those blocks are
        # strided by n_root and batched products over them run 6x slower.
        return G.T


def _triangular_solve(L: np.ndarray, b: np.ndarray, transposed: bool = False) -> np.ndarray:
    """``L^-1 b`` (or ``L^-T b``) for a lower triangular ``L`` (p, p), Fortran, and
    right-hand sides ``b`` (p, k); a new array.  One right-hand side (the Newton
    loop's solves) goes through BLAS-2 ``dtrsv``: OpenBLAS's ``dtrsm`` is slower on a
    single column (alone: 0.27-0.30 against 0.09-0.10 ms at p = 1323, 0.044 against
    0.017 at 507; a solve with the paper case's tangent, forward, root and backward,
    2.5-2.9 against 3.8-4.4 ms, alternating in one process), the same to rounding."""
    if b.shape[1] == 1:
        return blas.dtrsv(L, b[:, 0], lower=1, trans=int(transposed))[:, None]
    return blas.dtrsm(1.0, L, b, lower=1, trans_a=int(transposed))


def factorise(structure: SupernodalStructure, data: np.ndarray) -> SupernodalFactor:
    """Multifrontal Cholesky factorisation.

    Parameters
    ----------
    structure : SupernodalStructure
    data : ndarray, shape (nnz,)
        Values of the full matrix in the CSR layout the structure was built
        from (``K.data`` of :func:`fe_contact.fem.assembly.assemble_matrix`).

    Returns
    -------
    SupernodalFactor

    Raises
    ------
    NotPositiveDefinite
        If a pivot block is not positive definite (the caller may fall back
        to an LU factorisation).
    """
    st = structure
    diagonal, below = [], []
    updates: dict[int, np.ndarray] = {}
    pending: dict[int, list[int]] = {}
    for s in range(st.n_parts):
        p = int(st.starts[s + 1] - st.starts[s])
        q = st.boundary[s].size
        # the front (p + q) x (p + q) in two pieces, its upper right block
        # (never used) left out: the pivot columns and the boundary block,
        # which the rank update overwrites in place to become this part's
        # update (contiguous, so BLAS needs no copy of it)
        panel = np.zeros((p + q, p), order="F")
        corner = np.zeros((q, q), order="F")
        panel.ravel(order="F")[st.target[s]] = data[st.source[s]]  # the part's own columns
        for c in pending.pop(s, ()):
            _extend_add(panel, corner, updates.pop(c), st.relative[c])
        # in place where the pivot block is the whole front (the contact part)
        L, info = lapack.dpotrf(panel[:p], lower=1, clean=1, overwrite_a=1)
        if info != 0:
            raise NotPositiveDefinite(f"pivot block of part {s} ({p} dofs) is not positive definite (dpotrf info {info})")
        diagonal.append(L)
        if q:
            # rows of L below the block: F_bs L^-T; update F_bb - (F_bs L^-T)(F_bs L^-T)^T
            Y = blas.dtrsm(1.0, L, panel[p:], side=1, lower=1, trans_a=1)
            below.append(np.asfortranarray(Y))
            updates[s] = blas.dsyrk(-1.0, Y, beta=1.0, c=corner, trans=0, lower=1, overwrite_c=1)
            pending.setdefault(int(st.parent[s]), []).append(s)
        else:
            below.append(np.zeros((0, p), order="F"))
        del panel, corner
    return SupernodalFactor(st, diagonal, below)
