"""Sparse assembly of element matrices and vectors (node-major dofs).

Dof numbering: ``dof = 3 * node + component``; an element's 24 local dofs are
ordered ``(a, i) -> 3 * a + i`` for local node ``a`` and component ``i``.

The CSR structure of the global matrix depends only on the connectivity, so it
is computed once (:func:`sparsity_pattern`) together with the position in the
CSR data array of every entry of the ``(E, 24, 24)`` element matrices. Assembly
is then one ``np.bincount`` over that map; a ``np.add.at`` version is several
times slower (see the module tests / benchmark notes in the issue).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = [
    "SparsityPattern",
    "element_dofs",
    "check_pattern",
    "sparsity_pattern",
    "assemble_matrix",
    "assemble_vector",
]


def _check_elements(elements, n_nodes: int) -> np.ndarray:
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, (int, np.integer)) or n_nodes < 1:
        raise ValueError(f"n_nodes must be an integer >= 1, got {n_nodes!r}")
    arr = np.asarray(elements)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"elements must be an integer array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 8 or arr.shape[0] == 0:
        raise ValueError(f"elements must have shape (n_elems >= 1, 8), got {arr.shape}")
    if arr.min() < 0 or arr.max() >= n_nodes:
        raise ValueError(
            f"elements node ids must lie in [0, {n_nodes - 1}], "
            f"got range [{arr.min()}, {arr.max()}]"
        )
    return arr.astype(np.int64, copy=False)


def element_dofs(elements) -> np.ndarray:
    """Global dofs of each element.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elems, 8)

    Returns
    -------
    ndarray of int64, shape (n_elems, 24)
        ``dofs[e, 3*a + i] = 3 * elements[e, a] + i``.
    """
    elements = np.asarray(elements, dtype=np.int64)
    return (3 * elements[:, :, None] + np.arange(3)[None, None, :]).reshape(elements.shape[0], -1)


@dataclass(frozen=True)
class SparsityPattern:
    """CSR structure of the global ``(n_dofs, n_dofs)`` matrix and its scatter map.

    Attributes
    ----------
    n_dofs : int
        ``3 * n_nodes``.
    indptr : ndarray of int32, shape (n_dofs + 1,)
    indices : ndarray of int32, shape (nnz,)
        Column indices, sorted within each row.
    scatter : ndarray of int64, shape (n_elems * 576,)
        CSR data position of every entry of the C-ordered ``(E, 24, 24)``
        element-matrix array.
    dofs : ndarray of int64, shape (n_elems, 24)
        Global dofs of each element (see :func:`element_dofs`).
    """

    n_dofs: int
    indptr: np.ndarray
    indices: np.ndarray
    scatter: np.ndarray
    dofs: np.ndarray

    def __post_init__(self) -> None:
        for name in ("indptr", "indices", "scatter", "dofs"):
            getattr(self, name).setflags(write=False)
        if self.indptr.shape != (self.n_dofs + 1,):
            raise ValueError(
                f"indptr must have shape ({self.n_dofs + 1},), got {self.indptr.shape}"
            )
        if self.scatter.shape != (self.dofs.shape[0] * 576,):
            raise ValueError(
                f"scatter must have shape ({self.dofs.shape[0] * 576},), got {self.scatter.shape}"
            )

    @property
    def nnz(self) -> int:
        """Number of stored entries."""
        return int(self.indices.size)

    @property
    def n_elements(self) -> int:
        """Number of elements the pattern was built for."""
        return int(self.dofs.shape[0])


def sparsity_pattern(elements, n_nodes: int) -> SparsityPattern:
    """Build the CSR pattern of the assembled hex8 stiffness matrix.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elems, 8)
        Connectivity.
    n_nodes : int
        Number of nodes; the matrix is ``(3 n_nodes, 3 n_nodes)``.

    Returns
    -------
    SparsityPattern
        ``indptr`` and ``indices`` are int32 unless ``3 n_nodes`` or the number
        of nonzeros does not fit, then int64 (scipy's default index type).

    Raises
    ------
    ValueError
        If ``elements`` has the wrong shape or ids outside ``[0, n_nodes)``.

    Notes
    -----
    The pattern is built at node level (64 node pairs per element instead of
    576 dof pairs) and expanded to 3x3 dof blocks: with ``deg[a]`` the number
    of distinct nodes sharing an element with node ``a`` (``a`` included) and
    ``ptr`` the node-level CSR offsets, dof row ``3a + i`` starts at
    ``9 ptr[a] + 3 i deg[a]`` and holds, for each neighbour ``b`` in increasing
    order, the columns ``3b, 3b + 1, 3b + 2``. The result is identical to
    taking ``np.unique`` of the 576 dof-pair keys of every element.
    """
    elements = _check_elements(elements, n_nodes)
    n_nodes = int(n_nodes)
    n_dofs = 3 * n_nodes
    # Row-major node-pair keys sort in CSR order, so np.unique gives the
    # node-level structure and, through its inverse, the pair of every entry.
    keys = (elements[:, :, None] * n_nodes + elements[:, None, :]).ravel()
    pairs, pair_of = np.unique(keys, return_inverse=True)
    pair_rows = pairs // n_nodes
    pair_cols = pairs - pair_rows * n_nodes
    degree = np.bincount(pair_rows, minlength=n_nodes)
    node_ptr = np.zeros(n_nodes + 1, dtype=np.int64)
    np.cumsum(degree, out=node_ptr[1:])
    indptr, indices = _dof_rows(pair_cols, degree, node_ptr)
    return SparsityPattern(
        n_dofs=n_dofs,
        indptr=indptr,
        indices=indices,
        scatter=_scatter_positions(elements, pair_of, degree, node_ptr),
        dofs=element_dofs(elements),
    )


def _dof_rows(pair_cols: np.ndarray, degree: np.ndarray, node_ptr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dof-level CSR ``indptr`` (3 n_nodes + 1,) and ``indices`` (9 n_pairs,) from the
    node-level one (``pair_cols`` the column node of each pair in CSR order, ``degree`` and
    ``node_ptr`` per node): int32 unless an index would overflow it (scipy's default)."""
    n_dofs, nnz = 3 * degree.size, 9 * pair_cols.size
    three = np.arange(3)
    index_dtype = np.int32 if max(n_dofs, nnz) < np.iinfo(np.int32).max else np.int64
    row_start = (9 * node_ptr[:-1, None] + 3 * degree[:, None] * three).ravel()
    indptr = np.empty(n_dofs + 1, dtype=index_dtype)
    indptr[:-1] = row_start
    indptr[-1] = nnz
    # Dof row 3a + i is the slice [3 ptr[a], 3 ptr[a+1]) of the pair columns
    # expanded to (3b, 3b + 1, 3b + 2): gather it by shifting each row's range.
    pair_dof_cols = ((3 * pair_cols)[:, None] + three).astype(index_dtype).ravel()
    shift = np.repeat(3 * node_ptr[:-1], 3) - row_start
    indices = pair_dof_cols[np.arange(nnz) + np.repeat(shift, np.repeat(3 * degree, 3))]
    return indptr, indices


def _scatter_positions(elements: np.ndarray, pair_of: np.ndarray, degree: np.ndarray,
                       node_ptr: np.ndarray) -> np.ndarray:
    """Position in the CSR data of every element matrix entry, (n_elems * 576,) int64,
    ordered as the element matrices ``(e, 3a + i, 3b + j)``."""
    n_elems = elements.shape[0]
    three = np.arange(3)
    # Entry (e, 3a+i, 3b+j), with p the pair (elements[e, a], elements[e, b]) and
    # A = elements[e, a], sits at 9 ptr[A] + 3 i deg[A] + 3 (p - ptr[A]) + j.
    pair_base = (6 * node_ptr[elements])[:, :, None] + 3 * pair_of.reshape(n_elems, 8, 8)
    col_part = (pair_base[:, :, :, None] + three).reshape(n_elems, 8, 1, 24)  # (e, a, 1, 3b+j)
    row_part = ((3 * degree[elements])[:, :, None] * three)[:, :, :, None]  # (e, a, i, 1)
    scatter = np.empty((n_elems, 8, 3, 24), dtype=np.int64)
    np.add(col_part, row_part, out=scatter)
    return scatter.reshape(-1)


def check_pattern(pattern, elements: np.ndarray, n_nodes: int) -> None:
    """Raise ValueError unless ``pattern`` is the :class:`SparsityPattern` of ``elements``
    (n_elems, 8) on ``n_nodes`` nodes."""
    if not isinstance(pattern, SparsityPattern):
        raise ValueError(f"pattern must be a SparsityPattern, got {type(pattern).__name__}")
    if pattern.n_dofs != 3 * n_nodes or pattern.n_elements != elements.shape[0]:
        raise ValueError(
            f"pattern is for {pattern.n_elements} elements / {pattern.n_dofs} dofs, got "
            f"{elements.shape[0]} elements / {3 * n_nodes} dofs"
        )
    if not np.array_equal(pattern.dofs, element_dofs(elements)):
        raise ValueError("pattern was built for a different connectivity than elements")


def assemble_matrix(pattern: SparsityPattern, element_matrices) -> sp.csr_matrix:
    """Sum element matrices into the global sparse matrix.

    Parameters
    ----------
    pattern : SparsityPattern
        From :func:`sparsity_pattern` for the same connectivity.
    element_matrices : ndarray, shape (n_elems, 24, 24)
        Local matrices in the ``3*a + i`` dof order.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_dofs, n_dofs)
        Owns fresh ``indptr``/``indices`` copies, so callers may modify it.

    Raises
    ------
    ValueError
        If the element-matrix array does not match the pattern.
    """
    if not isinstance(pattern, SparsityPattern):
        raise ValueError(f"pattern must be a SparsityPattern, got {type(pattern).__name__}")
    ke = np.asarray(element_matrices, dtype=np.float64)
    if ke.shape != (pattern.n_elements, 24, 24):
        raise ValueError(
            f"element_matrices must have shape ({pattern.n_elements}, 24, 24), got {ke.shape}"
        )
    data = np.bincount(pattern.scatter, weights=ke.ravel(), minlength=pattern.nnz)
    matrix = sp.csr_matrix(
        (data, pattern.indices.copy(), pattern.indptr.copy()),
        shape=(pattern.n_dofs, pattern.n_dofs),
    )
    matrix.has_sorted_indices = True
    return matrix


def assemble_vector(elements, element_vectors, n_nodes: int) -> np.ndarray:
    """Sum element vectors into the global vector.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elems, 8)
    element_vectors : ndarray, shape (n_elems, 24) or (n_elems, 8, 3)
        Local vectors in the ``3*a + i`` dof order.
    n_nodes : int

    Returns
    -------
    ndarray, shape (3 * n_nodes,)

    Raises
    ------
    ValueError
        If the shapes do not match.
    """
    elements = _check_elements(elements, n_nodes)
    fe = np.asarray(element_vectors, dtype=np.float64)
    n_elems = elements.shape[0]
    if fe.shape not in ((n_elems, 24), (n_elems, 8, 3)):
        raise ValueError(
            f"element_vectors must have shape ({n_elems}, 24) or ({n_elems}, 8, 3), got {fe.shape}"
        )
    return np.bincount(element_dofs(elements).ravel(), weights=fe.ravel(), minlength=3 * n_nodes)
