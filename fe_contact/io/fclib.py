"""Local frictional contact problems in the FCLIB HDF5 format (Siconos / LMGC90).

An FCLIB local problem ``FC(W, q, mu)`` is isotropic: one Coulomb coefficient per
contact.  An anisotropic (elliptic) problem with ``M = diag(mu_x, mu_y)`` in the
orthotropy frame maps onto it exactly by ``D = diag(1, mu_x, mu_y)`` per contact::

    W' = D W D,   q' = D q,   mu' = 1,   r = D s,   u' = D u

(``D K_1 = K_mu`` and the De Saxce velocity ``(u_n + ||M u_t||, u_t)`` is ``D^-1``
times the isotropic one, so ``s`` solves the isotropic problem iff ``r`` solves the
elliptic one).  Contacts whose cone is already circular (``mu_x == mu_y``,
frictionless included) are written as they are (``D = I``, ``mu' = mu_x``), so an
isotropic problem is stored as plain FCLIB.  A contact with exactly one zero
coefficient keeps the scaling with a zero in ``D``: every isotropic solution ``s``
still maps to a solution ``r = D s`` (``s = 0`` is written on that axis), and the
rows and columns of ``W`` that ``D`` erases are kept in the extra group.

The extra group ``/pushplan_anisotropy`` (ignored by other FCLIB readers) holds
``mu_x``, ``mu_y``, ``angle`` and the ``scaling`` diagonal ``D`` (shape (nc, 3)),
so that :func:`read_local_problem` restores the anisotropic problem.

Sparse matrices follow FCLIB's ``struct fclib_matrix`` as FCLIB and Siconos fill
it (the CSparse convention): ``nz >= 0`` triplet with ``p`` = column indices and
``i`` = row indices (checked on the triplet ``H`` of the LMGC90 global problem
``CubeH8.hdf5``; the comment in ``fclib.h`` says the opposite), ``nz = -1``
compressed columns (``p`` column pointers, ``i`` row indices), ``nz = -2``
compressed rows (``p`` row pointers, ``i`` column indices).
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import scipy.sparse as sp

from .hdf5_checked import CSR, dataset, group, read_array, read_sparse_matrix, read_string, scalar_int

__all__ = ["MAX_CONTACTS", "MAX_DENSE_BYTES", "LocalProblem", "read_local_problem", "read_sparse_matrix",
           "write_local_problem"]

ANISOTROPY_GROUP = "pushplan_anisotropy"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class LocalProblem:
    """A local 3D frictional contact problem ``u = W r + q``, elliptic Coulomb law.

    Attributes
    ----------
    W : ndarray, shape (3 nc, 3 nc)
        Flexibility (Delassus) matrix in local frames, ordered ``(n, t_x, t_y)`` per contact.
    q : ndarray, shape (nc, 3)
        Free local velocity (or displacement).
    mu_x, mu_y : ndarray, shape (nc,)
        Principal friction coefficients along ``t_x`` and ``t_y``.
    angle : ndarray, shape (nc,)
        Orthotropy angle of ``t_x`` from the world x axis, rad (0 if not stored).
    title, description : str
        FCLIB ``info`` strings.
    r_ref, u_ref : ndarray, shape (nc, 3), or None
        The file's ``/solution`` reaction and velocity, if stored.
    """

    W: np.ndarray
    q: np.ndarray
    mu_x: np.ndarray
    mu_y: np.ndarray
    angle: np.ndarray
    title: str
    description: str
    r_ref: np.ndarray | None
    u_ref: np.ndarray | None

    def __post_init__(self) -> None:
        q = _contact_array("q", self.q, None)
        nc = q.shape[0]
        W = _dense_flexibility(self.W, nc)
        mu_x = _coefficients("mu_x", self.mu_x, nc)
        mu_y = _coefficients("mu_y", self.mu_y, nc)
        angle = _per_contact("angle", self.angle, nc)
        r_ref = None if self.r_ref is None else _contact_array("r_ref", self.r_ref, nc)
        u_ref = None if self.u_ref is None else _contact_array("u_ref", self.u_ref, nc)
        for name, a in (("W", W), ("q", q), ("mu_x", mu_x), ("mu_y", mu_y), ("angle", angle),
                        ("r_ref", r_ref), ("u_ref", u_ref)):
            if a is not None:
                a.flags.writeable = False
            object.__setattr__(self, name, a)

    @property
    def n_contacts(self) -> int:
        """Number of contacts ``nc``."""
        return self.q.shape[0]

    @property
    def isotropic(self) -> bool:
        """True if ``mu_x == mu_y`` for every contact (circular cones)."""
        return bool(np.array_equal(self.mu_x, self.mu_y))


MAX_CONTACTS = 20_000
"""Most contacts :func:`read_local_problem` reads."""
MAX_DENSE_BYTES = 4 * 2**30
"""Largest dense ``W`` (8 (3 nc)^2 bytes) :func:`read_local_problem` builds by default:
4 GiB, 7723 contacts; checked on the declared shape before anything is read."""


def read_local_problem(path: str | os.PathLike, max_contacts: int = MAX_CONTACTS,
                       max_bytes: float = MAX_DENSE_BYTES) -> LocalProblem:
    """Read a local FCLIB problem, restoring the anisotropic one if our group is present.

    Every dataset is checked (:mod:`fe_contact.io.hdf5_checked`: a dataset, real
    numbers, the declared size) and the declared shapes consistent (``mu`` (nc,),
    ``q`` (3 nc,), ``W`` (3 nc, 3 nc), at most ``max_contacts`` contacts, a dense ``W``
    of at most ``max_bytes``) before anything of their size is read.

    Parameters
    ----------
    path : path of an HDF5 file with a ``/fclib_local`` group.
    max_contacts : int
        Largest problem read.
    max_bytes : float
        Largest dense ``W`` built, bytes (``8 (3 nc)^2``).

    Returns
    -------
    LocalProblem

    Raises
    ------
    ValueError
        Not an HDF5 file, not a 3D local problem, a mixed problem (``V``, ``R``), a
        missing or malformed dataset, or inconsistent data (file and dataset named).
    """
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: cannot open as HDF5 ({' '.join(str(exc).split())[:100]})") from None
    with f:
        if not isinstance(group(f, "fclib_local", optional=True), h5py.Group):
            raise ValueError(f"{path}: no /fclib_local group (not a local FCLIB problem)")
        loc = f["fclib_local"]
        info = group(loc, "info", optional=True)
        spacedim = scalar_int(loc, "spacedim")
        if spacedim != 3:
            raise ValueError(f"{path}: spacedim must be 3, got {spacedim}")
        if "V" in loc or "R" in loc:
            raise ValueError(f"{path}: mixed local problems (V, R, s) are not supported")
        nc = _declared_contacts(path, loc, max_contacts, max_bytes)
        W = read_sparse_matrix(loc["W"]).toarray()
        q = read_array(loc, "vectors/q", (3 * nc,)).reshape(nc, 3)
        mu = read_array(loc, "vectors/mu", (nc,))
        title, description = ("", "") if info is None else (read_string(info, "title"), read_string(info, "description"))
        r = _read_vector(f, "solution/r", nc)
        u = _read_vector(f, "solution/u", nc)
        try:  # the values' own checks (finite, mu >= 0) named with the file
            if group(f, ANISOTROPY_GROUP, optional=True) is None:
                return LocalProblem(W, q, mu, mu.copy(), np.zeros(nc), title, description, r, u)
            return _unscaled(f[ANISOTROPY_GROUP], W, q, mu, r, u, title, description, str(path))
        except ValueError as exc:
            message = str(exc)
            raise ValueError(message if message.startswith(str(path)) else f"{path}: {message}") from None


def _declared_contacts(path, loc: h5py.Group, max_contacts: int, max_bytes: float) -> int:
    """The number of contacts ``nc`` from the declared shapes, checked before reading."""
    nc = dataset(loc, "vectors/mu").size
    q_set = dataset(loc, "vectors/q")
    if q_set.shape not in ((3 * nc,), (nc, 3)):
        raise ValueError(f"{path}: /fclib_local/vectors/q has shape {q_set.shape}, expected ({3 * nc},) "
                         f"for the {nc} contacts of mu")
    if nc < 1 or nc > max_contacts:
        raise ValueError(f"{path}: {nc} contacts (mu), expected 1 to {max_contacts}")
    if 8.0 * (3 * nc) ** 2 > max_bytes:
        raise ValueError(f"{path}: {nc} contacts need a dense W of {8.0 * (3 * nc) ** 2 / 1e9:.3g} GB, more "
                         f"than the {max_bytes / 1e9:.3g} GB allowed (max_bytes)")
    group(loc, "W")
    shape = tuple(scalar_int(loc, f"W/{k}") for k in ("m", "n"))
    if shape != (3 * nc, 3 * nc):
        raise ValueError(f"{path}: /fclib_local/W is declared {shape}, expected ({3 * nc}, {3 * nc}) "
                         f"for {nc} contacts")
    return nc


def write_local_problem(
    path: str | os.PathLike,
    W,
    q,
    mu_x,
    mu_y,
    angle=0.0,
    title: str = "",
    description: str = "",
    r=None,
    u=None,
) -> None:
    """Write an (an)isotropic local problem as FCLIB, scaled to isotropic form.

    The file is written to a temporary name in the same directory and renamed,
    so an existing file is replaced whole or not at all.

    Parameters
    ----------
    path : destination file.
    W : ndarray or scipy sparse, shape (3 nc, 3 nc)
        Flexibility matrix, local ``(n, t_x, t_y)`` ordering.
    q : ndarray, shape (nc, 3) or (3 nc,)
    mu_x, mu_y : float or ndarray, shape (nc,), >= 0
    angle : float or ndarray, shape (nc,), rad
    title, description : str
    r, u : ndarray, shape (nc, 3) or (3 nc,), optional
        A solution (both or neither), written to ``/solution`` in scaled form.

    Raises
    ------
    ValueError
        Bad shapes, non-finite values, negative coefficients, or only one of ``r``, ``u``.
    """
    q, Wc, mu_x, mu_y, angle, r, u = _checked_problem(W, q, mu_x, mu_y, angle, title, description, r, u)
    D, mu_prime = _scaling(mu_x, mu_y)
    d = D.ravel()
    rows = np.repeat(np.arange(Wc.shape[0]), np.diff(Wc.indptr))
    Ws = sp.csr_array(((d[rows] * Wc.data) * d[Wc.indices], Wc.indices, Wc.indptr), shape=Wc.shape)
    scaled = bool(np.any(D != 1.0))
    math_info = ("anisotropic problem scaled to isotropic form, r = D s, u' = D u; "
                 f"D and the coefficients are in /{ANISOTROPY_GROUP}") if scaled else ""

    def write(f: h5py.File) -> None:
        _write_scaled(f, Ws, D, q, mu_prime, {"title": title, "description": description, "math_info": math_info},
                      r, u)
        _write_anisotropy(f.create_group(ANISOTROPY_GROUP), mu_x, mu_y, angle, D, Wc, q, r, u)

    _atomic_write(Path(path), write)


def _checked_problem(W, q, mu_x, mu_y, angle, title, description, r, u):
    """:func:`write_local_problem`'s inputs checked and as float arrays: ``q`` (nc, 3),
    ``W`` CSR (3 nc, 3 nc), ``mu_x``, ``mu_y``, ``angle`` (nc,), ``r``, ``u`` (nc, 3) or None."""
    q = _contact_array("q", q, None)
    nc = q.shape[0]
    if nc == 0:
        raise ValueError("q must describe at least one contact, got shape (0, 3)")
    Wc = _sparse_flexibility(W, nc)
    mu_x = _coefficients("mu_x", mu_x, nc)
    mu_y = _coefficients("mu_y", mu_y, nc)
    angle = _per_contact("angle", angle, nc)
    if (r is None) != (u is None):
        raise ValueError("r and u must be given together (FCLIB stores a solution as both)")
    r = None if r is None else _contact_array("r", r, nc)
    u = None if u is None else _contact_array("u", u, nc)
    for name, s in (("title", title), ("description", description)):
        if not isinstance(s, str):
            raise ValueError(f"{name} must be a str, got {type(s).__name__}")
    return q, Wc, mu_x, mu_y, angle, r, u


def _write_scaled(f: h5py.File, Ws: sp.csr_array, D: np.ndarray, q: np.ndarray, mu_prime: np.ndarray,
                  info: dict[str, str], r, u) -> None:
    """The FCLIB groups of the scaled problem: ``/fclib_local`` (``W' = D W D``, ``q' = D q``,
    ``mu'``, the ``info`` strings) and, with a solution, ``/solution`` (``s = r / D``, ``u' = D u``;
    ``s = 0`` where ``D`` is 0)."""
    loc = f.create_group("fclib_local")
    _int_scalar(loc, "spacedim", 3)
    _write_sparse_matrix(loc.create_group("W"), Ws)
    vec = loc.create_group("vectors")
    vec.create_dataset("q", data=(D * q).ravel())
    vec.create_dataset("mu", data=mu_prime)
    group_info = loc.create_group("info")
    for name, text in info.items():
        _write_string(group_info, name, text)
    if r is not None:
        sol = f.create_group("solution")
        s = np.where(D == 0.0, 0.0, r / np.where(D == 0.0, 1.0, D))
        sol.create_dataset("r", data=s.ravel())
        sol.create_dataset("u", data=(D * u).ravel())


def _write_anisotropy(g: h5py.Group, mu_x, mu_y, angle, D, Wc, q, r, u) -> None:
    """The ``/pushplan_anisotropy`` group: coefficients, orthotropy angles,
    scaling ``D`` (nc, 3), and the rows, columns and entries of ``W``, ``q``
    (and ``r``, ``u``) at the components ``D`` zeroes (a zero coefficient),
    which the scaled problem no longer holds."""
    zero = np.flatnonzero(D.ravel() == 0.0)
    g.attrs["format_version"] = FORMAT_VERSION
    g.attrs["mapping"] = "W' = D W D, q' = D q, r = D s, u' = D u, D = diag(scaling[c]) per contact"
    for name, a in (("mu_x", mu_x), ("mu_y", mu_y), ("angle", angle), ("scaling", D)):
        g.create_dataset(name, data=a)
    if zero.size:
        g.create_dataset("degenerate_index", data=zero.astype(np.int64))
        _write_sparse_matrix(g.create_group("W_degenerate_rows"), Wc[zero, :])
        _write_sparse_matrix(g.create_group("W_degenerate_cols_T"), Wc.T.tocsr()[zero, :])
        g.create_dataset("q_degenerate", data=q.ravel()[zero])
        if r is not None:
            g.create_dataset("r_degenerate", data=r.ravel()[zero])
            g.create_dataset("u_degenerate", data=u.ravel()[zero])


# --------------------------------------------------------------------------- helpers


def _scaling(mu_x: np.ndarray, mu_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-contact ``D`` (nc, 3) and isotropic coefficient ``mu'`` (nc,)."""
    circular = mu_x == mu_y
    D = np.column_stack([np.ones_like(mu_x), mu_x, mu_y])
    D[circular, 1:] = 1.0
    return D, np.where(circular, mu_x, 1.0)


def _unscaled(g: h5py.Group, Wp: np.ndarray, qp: np.ndarray, mu_p: np.ndarray, s, up,
              title: str, description: str, where: str) -> LocalProblem:
    """Undo :func:`write_local_problem`'s scaling with the data of our extra group."""
    nc = qp.shape[0]
    mu_x = _coefficients("mu_x", read_array(g, "mu_x", (1, nc)), nc)
    mu_y = _coefficients("mu_y", read_array(g, "mu_y", (1, nc)), nc)
    angle = _per_contact("angle", read_array(g, "angle", (1, nc)), nc)
    D = read_array(g, "scaling", (3 * nc,)).reshape(nc, 3)
    if D.shape != (nc, 3) or np.any(D[:, 0] != 1.0) or np.any(D < 0) or not np.all(np.isfinite(D)):
        raise ValueError(f"{where}: /{ANISOTROPY_GROUP}/scaling must be (nc, 3) = (1, >=0, >=0), got {D.shape}")
    # The FCLIB cone ||s_t|| <= mu' s_n mapped by D must be the stored elliptic cone.
    if not (np.array_equal(mu_p * D[:, 1], mu_x) and np.array_equal(mu_p * D[:, 2], mu_y)):
        raise ValueError(f"{where}: FCLIB mu and /{ANISOTROPY_GROUP} (scaling, mu_x, mu_y) disagree")
    d = D.ravel()
    keep = d != 0.0
    zero = np.flatnonzero(~keep)
    W = np.zeros_like(Wp)
    W[np.ix_(keep, keep)] = (Wp[np.ix_(keep, keep)] / d[keep][:, None]) / d[keep][None, :]
    q = np.zeros(3 * nc)
    q[keep] = qp.ravel()[keep] / d[keep]
    r = None if s is None else (D * s).ravel()
    u = None if up is None else np.where(keep, up.ravel() / np.where(keep, d, 1.0), 0.0)
    if zero.size:
        if not np.array_equal(read_array(g, "degenerate_index", (zero.size,), integer=True), zero):
            raise ValueError(f"{where}: /{ANISOTROPY_GROUP}/degenerate_index does not match the zeros of scaling")
        W[zero, :] = _sparse_block(g, "W_degenerate_rows", (zero.size, 3 * nc))
        W[:, zero] = _sparse_block(g, "W_degenerate_cols_T", (zero.size, 3 * nc)).T
        q[zero] = read_array(g, "q_degenerate", (zero.size,))
        if r is not None and u is not None:
            r[zero] = read_array(g, "r_degenerate", (zero.size,))
            u[zero] = read_array(g, "u_degenerate", (zero.size,))
    return LocalProblem(W, q.reshape(nc, 3), mu_x, mu_y, angle, title, description,
                        None if r is None else r.reshape(nc, 3),
                        None if u is None else u.reshape(nc, 3))


def _sparse_block(g: h5py.Group, name: str, shape) -> np.ndarray:
    """The sparse matrix group ``name`` of ``g``, of the declared ``shape``, dense."""
    group(g, name)
    declared = tuple(scalar_int(g[name], k) for k in ("m", "n"))
    if declared != tuple(shape):
        raise ValueError(f"{g.file.filename}: {g.name}/{name} is declared {declared}, expected {tuple(shape)}")
    return read_sparse_matrix(g[name]).toarray()


def _write_sparse_matrix(g: h5py.Group, A: sp.csr_array) -> None:
    """Write ``A`` as an FCLIB compressed-row matrix (``nz = -2``)."""
    m, n = A.shape
    for name, value in (("nzmax", A.nnz), ("m", m), ("n", n), ("nz", CSR)):
        _int_scalar(g, name, value)
    g.create_dataset("p", data=A.indptr.astype(np.int32))
    g.create_dataset("i", data=A.indices.astype(np.int32))
    g.create_dataset("x", data=np.asarray(A.data, dtype=float))


def _int_scalar(g: h5py.Group, name: str, value: int) -> None:
    g.create_dataset(name, data=np.array([value], dtype=np.int32))


def _write_string(g: h5py.Group, name: str, text: str) -> None:
    raw = text.encode("utf-8")
    g.create_dataset(name, data=np.array(raw, dtype=f"S{max(len(raw), 1)}"))


def _read_vector(f: h5py.File, name: str, nc: int) -> np.ndarray | None:
    if name not in f:
        return None
    return read_array(f, name, (3 * nc,)).reshape(nc, 3)


def _atomic_write(path: Path, write) -> None:
    """Call ``write(h5py.File)`` on a temporary file next to ``path``, then rename it."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        with h5py.File(tmp, "w-") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _contact_array(name: str, v, nc: int | None) -> np.ndarray:
    """``(nc, 3)`` or ``(3 nc,)`` finite input as a float ``(nc, 3)`` copy."""
    a = np.array(v, dtype=float)
    if a.ndim == 1 and a.size % 3 == 0:
        a = a.reshape(-1, 3)
    if a.ndim != 2 or a.shape[1] != 3 or (nc is not None and a.shape[0] != nc):
        want = "(nc, 3) or (3 nc,)" if nc is None else f"({nc}, 3) or ({3 * nc},)"
        raise ValueError(f"{name} must have shape {want}, got {np.shape(v)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values")
    return a


def _per_contact(name: str, v, nc: int) -> np.ndarray:
    a = np.array(v, dtype=float)
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] != nc):
        raise ValueError(f"{name} must be a scalar or have shape ({nc},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.ravel()[~np.isfinite(a.ravel())][0]}")
    return np.broadcast_to(a, (nc,)).copy()


def _coefficients(name: str, v, nc: int) -> np.ndarray:
    a = _per_contact(name, v, nc)
    if np.any(a < 0):
        raise ValueError(f"{name} must be >= 0, got {a[a < 0][0]}")
    return a


def _dense_flexibility(W, nc: int) -> np.ndarray:
    a = W.toarray() if sp.issparse(W) else np.array(W, dtype=float)
    a = np.asarray(a, dtype=float)
    if a.shape != (3 * nc, 3 * nc):
        raise ValueError(f"W must have shape ({3 * nc}, {3 * nc}) for {nc} contacts, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("W contains non-finite values")
    return a


def _sparse_flexibility(W, nc: int) -> sp.csr_array:
    if sp.issparse(W):
        A = sp.csr_array(W, dtype=float, copy=True)
        A.sum_duplicates()
        A.sort_indices()
    else:
        A = sp.csr_array(_dense_flexibility(W, nc))
    if A.shape != (3 * nc, 3 * nc):
        raise ValueError(f"W must have shape ({3 * nc}, {3 * nc}) for {nc} contacts, got {A.shape}")
    if not np.all(np.isfinite(A.data)):
        raise ValueError("W contains non-finite values")
    return A
