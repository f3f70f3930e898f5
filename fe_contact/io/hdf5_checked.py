"""Checked reading of HDF5 datasets for the FCLIB reader: every dataset is checked to
be a dataset (not a group, not a broken or self-referencing link), of a numeric real
dtype (no compound, string or complex values), of the declared size, before anything
of its size is read; index arrays must hold integers.  Every message names the file
and the dataset.

Sparse matrices follow FCLIB's ``struct fclib_matrix`` (see :mod:`fe_contact.io.fclib`):
``nz >= 0`` triplet (``p`` column, ``i`` row indices), ``nz = -1`` compressed columns,
``nz = -2`` compressed rows.
"""

from __future__ import annotations

import h5py
import numpy as np
import scipy.sparse as sp

__all__ = ["dataset", "group", "read_array", "read_sparse_matrix", "read_string", "scalar_int"]

TRIPLET_MIN, CSC, CSR = 0, -1, -2
MAX_STRING_BYTES = 1 << 16
"""Longest ``info`` string read (64 KiB)."""


def _where(group: h5py.Group, name: str) -> str:
    return f"{group.file.filename}: {group.name.rstrip('/')}/{name}"


def dataset(group: h5py.Group, name: str) -> h5py.Dataset:
    """The dataset ``name`` of ``group``; ValueError naming file and dataset when it is
    absent, a group, or a link that cannot be followed (dangling, to itself)."""
    try:
        obj = group.get(name)
    except (KeyError, RuntimeError, OSError, ValueError) as exc:  # a link loop, an external file missing
        raise ValueError(f"{_where(group, name)} cannot be opened ({' '.join(str(exc).split())[:80]})") from None
    if not isinstance(obj, h5py.Dataset):
        raise ValueError(f"{_where(group, name)} is {'missing' if obj is None else 'a group, not a dataset'}")
    return obj


def group(parent: h5py.Group, name: str, optional: bool = False) -> h5py.Group | None:
    """The group ``name`` of ``parent`` (None when ``optional`` and absent); ValueError
    naming file and group when it is a dataset or a link that cannot be followed."""
    try:
        obj = parent.get(name)
    except (KeyError, RuntimeError, OSError, ValueError) as exc:
        raise ValueError(f"{_where(parent, name)} cannot be opened ({' '.join(str(exc).split())[:80]})") from None
    if obj is None and optional:
        return None
    if not isinstance(obj, h5py.Group):
        raise ValueError(f"{_where(parent, name)} must be a group, got {'nothing' if obj is None else 'a dataset'}")
    return obj


def _numeric(group: h5py.Group, name: str, d: h5py.Dataset, integer: bool) -> None:
    kinds = "iu" if integer else "iuf"
    if d.dtype.kind not in kinds and not (integer and d.dtype.kind == "f"):
        what = {"c": "complex", "V": "compound", "S": "text", "O": "text", "U": "text"}.get(d.dtype.kind, str(d.dtype))
        raise ValueError(f"{_where(group, name)} must hold real {'integers' if integer else 'numbers'}, "
                         f"got {what} values ({d.dtype})")


def read_array(group: h5py.Group, name: str, sizes=None, integer: bool = False) -> np.ndarray:
    """The dataset ``name`` as a flat float (or int64, ``integer``) array.

    ``sizes``: the allowed numbers of entries, checked on the declared shape before
    reading (None: any; the caller has bounded it).  ``integer``: floats must be whole
    (an index of 1.5 is refused)."""
    d = dataset(group, name)
    _numeric(group, name, d, integer)
    if sizes is not None and d.size not in tuple(sizes):
        raise ValueError(f"{_where(group, name)} declares {d.size} entries (shape {d.shape}), expected "
                         f"{' or '.join(str(s) for s in sizes)}")
    a = np.asarray(d[()]).ravel()
    if not integer:
        return a.astype(float)
    if a.dtype.kind == "f" and not np.all(np.isfinite(a) & (a == np.round(a))):
        bad = a[~(np.isfinite(a) & (a == np.round(a)))][0]
        raise ValueError(f"{_where(group, name)} must hold integers, got {bad}")
    return a.astype(np.int64)


def scalar_int(group: h5py.Group, name: str) -> int:
    """The integer in the one-element dataset ``name`` of ``group``."""
    d = dataset(group, name)
    if d.size != 1:
        raise ValueError(f"{_where(group, name)} must hold one number, got shape {d.shape} of {d.dtype}")
    return int(read_array(group, name, (1,), integer=True)[0])


def read_string(group: h5py.Group, name: str) -> str:
    """The text dataset ``name`` of ``group`` ("" when absent); at most
    :data:`MAX_STRING_BYTES`."""
    if name not in group:
        return ""
    d = dataset(group, name)
    if d.dtype.kind not in "SOU" or d.size != 1 or d.dtype.itemsize > MAX_STRING_BYTES:
        raise ValueError(f"{_where(group, name)} must be one string, got shape {d.shape} of {d.dtype}")
    v = d[()]
    v = v.ravel()[0] if isinstance(v, np.ndarray) else v
    if isinstance(v, bytes):
        if len(v) > MAX_STRING_BYTES:
            raise ValueError(f"{_where(group, name)} is longer than {MAX_STRING_BYTES} bytes")
        return v.decode("utf-8", errors="replace")
    return str(v)[:MAX_STRING_BYTES]


def read_sparse_matrix(group: h5py.Group) -> sp.csr_array:
    """Read an FCLIB ``fclib_matrix`` group ``{m, n, nz, nzmax, p, i, x}``.

    Duplicate triplet entries are summed.

    Raises
    ------
    ValueError
        Unknown ``nz`` code, arrays inconsistent with ``m``, ``n`` (checked on the
        declared sizes before reading), fractional indices, non-numeric values.
    """
    where = f"{group.file.filename}: {group.name}"
    m, n, nz = (scalar_int(group, k) for k in ("m", "n", "nz"))
    if m < 0 or n < 0:
        raise ValueError(f"{where}: negative shape ({m}, {n})")
    limit = m * n + max(m, n) + 1  # no layout stores more entries than a dense matrix
    sizes = {k: dataset(group, k).size for k in ("p", "i", "x")}
    if max(sizes.values()) > limit:
        raise ValueError(f"{where}: datasets p, i, x of {sizes['p']}, {sizes['i']}, {sizes['x']} entries "
                         f"for a ({m}, {n}) matrix")
    p, i = read_array(group, "p", integer=True), read_array(group, "i", integer=True)
    x = read_array(group, "x")
    if nz >= TRIPLET_MIN:
        if min(p.size, i.size, x.size) < nz:
            raise ValueError(f"{where}: triplet with nz={nz} but p, i, x have {p.size}, {i.size}, {x.size} entries")
        return checked_coo(where, x[:nz], i[:nz], p[:nz], (m, n)).tocsr()
    if nz not in (CSC, CSR):
        raise ValueError(f"{where}: unknown sparse layout nz={nz} (expected >= 0, -1 or -2)")
    n_ptr = (n if nz == CSC else m) + 1
    if p.size != n_ptr or p[0] != 0 or np.any(np.diff(p) < 0) or min(i.size, x.size) < p[-1]:
        raise ValueError(f"{where}: compressed pointers (nz={nz}) inconsistent with shape ({m}, {n}) "
                         f"and {i.size} indices")
    idx, val = i[: p[-1]], x[: p[-1]]
    major = np.repeat(np.arange(n_ptr - 1), np.diff(p))
    rows, cols = (idx, major) if nz == CSC else (major, idx)
    return checked_coo(where, val, rows, cols, (m, n)).tocsr()


def checked_coo(where: str, x: np.ndarray, rows: np.ndarray, cols: np.ndarray, shape) -> sp.coo_array:
    """The COO matrix of the triplets, indices checked in range."""
    m, n = shape
    if rows.size and (rows.min() < 0 or rows.max() >= m or cols.min() < 0 or cols.max() >= n):
        raise ValueError(f"{where}: indices out of range for shape ({m}, {n}): rows "
                         f"[{rows.min()}, {rows.max()}], columns [{cols.min()}, {cols.max()}]")
    return sp.coo_array((x, (rows, cols)), shape=shape)
