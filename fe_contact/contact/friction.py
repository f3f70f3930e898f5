"""Elliptic (orthotropic) Coulomb cone of the paper, sect. 3-5.

Contact vectors are arrays of shape ``(n_contacts, 3)`` ordered ``(n, t_x, t_y)``
in the local frame whose tangent axes are the orthotropy axes: ``mu_x`` acts
along ``t_x`` and ``mu_y`` along ``t_y``.  With ``M = diag(mu_x, mu_y)``:

* friction cone ``K_mu = {r : ||M^-1 r_t|| <= r_n}`` (eq. 15),
* its polar cone ``K_mu° = {v : v_n + ||M v_t|| <= 0}`` (eq. 22),
* the De Saxcé modified velocity ``(u_n + ||M u_t||, u_t)``.

A zero coefficient is allowed: ``mu_i = 0`` forces ``r_ti = 0`` and the cone
degenerates (for ``mu_x = mu_y = 0``) to the half-line ``r_t = 0, r_n >= 0`` of
frictionless contact.  All functions accept scalar or per-contact coefficients.
"""

from __future__ import annotations

import math

import numpy as np

from ._kernels import _project_kernel  # compiled: the per-contact projection (_kernels.pyx)

__all__ = [
    "elliptic_norm",
    "dual_elliptic_norm",
    "in_cone",
    "in_polar_cone",
    "modified_velocity",
    "project_elliptic_cone",
    "local_frame",
    "frame_derivative",
    "to_local",
    "to_global",
    "scaling_diagonal",
    "MU_MAX",
]


MU_MAX = 1e3
"""Largest friction coefficient (each of ``mu_x``, ``mu_y``; any value from 0 up is
allowed below it, a tiny one included).  Measured friction is below 10 (rubber on
rubber 1-4).  Beyond about 1e8 the projection's ``1 + mu^2`` terms lose the normal
component (NaN for ``mu_x = 1e200, mu_y = 0.1``) and the contact loop reported a
converged press with the lower face 58-100 um inside the plane (``mu = 1e7``); at
``MU_MAX`` a press holds the contact law (``tests/test_hardening_api.py``)."""


def _real_array(name: str, v) -> np.ndarray:
    """``v`` as a float array; a complex value is refused (numpy would drop its
    imaginary part with only a warning)."""
    if np.iscomplexobj(v) or (np.ndim(v) == 0 and isinstance(v, complex)):
        raise ValueError(f"{name} must be real, got a complex value")
    return np.asarray(v, dtype=float)


def _as_contacts(name: str, v) -> np.ndarray:
    a = _real_array(name, v)
    if a.ndim == 1 and a.shape[0] == 3:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n_contacts, 3), got {np.shape(v)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite values")
    return a


def _as_coefficients(mu_x, mu_y, n: int) -> tuple[np.ndarray, np.ndarray]:
    out = []
    for name, mu in (("mu_x", mu_x), ("mu_y", mu_y)):
        m = _real_array(name, mu)
        if m.ndim > 1 or (m.ndim == 1 and m.shape[0] != n):
            raise ValueError(f"{name} must be a scalar or have shape ({n},), got {m.shape}")
        ok = np.isfinite(m) & (m >= 0) & (m <= MU_MAX)
        if not np.all(ok):
            bad = m[~ok] if m.ndim else m
            raise ValueError(f"{name} must be finite, >= 0 and <= {MU_MAX:g}, got {np.ravel(bad)[0]}")
        out.append(np.broadcast_to(m, (n,)).astype(float))
    return out[0], out[1]


def _row_norms(a: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``a`` without overflow or underflow of the squares."""
    m = np.max(np.abs(a), axis=1)
    safe = np.where(m > 0, m, 1.0)
    return m * np.linalg.norm(a / safe[:, None], axis=1)


def _prepare(name, v, mu_x, mu_y):
    a = _as_contacts(name, v)
    mx, my = _as_coefficients(mu_x, mu_y, a.shape[0])
    return a, mx, my


def elliptic_norm(r_t, mu_x, mu_y) -> np.ndarray:
    """``||M^-1 r_t||`` (eq. 14) for tangential vectors ``r_t`` of shape (n, 2).

    A component along an axis with zero friction contributes ``inf`` unless it is 0.
    """
    rt = np.atleast_2d(np.asarray(r_t, dtype=float))
    if rt.shape[-1] != 2:
        raise ValueError(f"r_t must have shape (n_contacts, 2), got {np.shape(r_t)}")
    mx, my = _as_coefficients(mu_x, mu_y, rt.shape[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        cx = np.where(rt[:, 0] == 0.0, 0.0, rt[:, 0] / mx)
        cy = np.where(rt[:, 1] == 0.0, 0.0, rt[:, 1] / my)
    return np.hypot(cx, cy)


def dual_elliptic_norm(v_t, mu_x, mu_y) -> np.ndarray:
    """``||M v_t||`` (eq. 21), the support function of the friction ellipse."""
    vt = np.atleast_2d(np.asarray(v_t, dtype=float))
    if vt.shape[-1] != 2:
        raise ValueError(f"v_t must have shape (n_contacts, 2), got {np.shape(v_t)}")
    mx, my = _as_coefficients(mu_x, mu_y, vt.shape[0])
    return np.hypot(mx * vt[:, 0], my * vt[:, 1])


def in_cone(r, mu_x, mu_y, tol: float = 0.0) -> np.ndarray:
    """Boolean mask: ``r`` in ``K_mu`` up to ``tol * ||r||``."""
    a, mx, my = _prepare("r", r, mu_x, mu_y)
    slack = tol * _row_norms(a)
    # an axis without friction must carry no force; the others enter ||M^-1 r_t||
    with np.errstate(over="ignore"):  # inf for a tiny mu is the right answer: outside
        cx = np.where(mx > 0, a[:, 1] / np.where(mx > 0, mx, 1.0), 0.0)
        cy = np.where(my > 0, a[:, 2] / np.where(my > 0, my, 1.0), 0.0)
    free_ok = (np.where(mx > 0, 0.0, np.abs(a[:, 1])) <= slack) & (
        np.where(my > 0, 0.0, np.abs(a[:, 2])) <= slack
    )
    return (np.hypot(cx, cy) <= a[:, 0] + slack) & free_ok


def in_polar_cone(v, mu_x, mu_y, tol: float = 0.0) -> np.ndarray:
    """Boolean mask: ``v`` in the polar cone, ``v_n + ||M v_t|| <= tol * ||v||``."""
    a, mx, my = _prepare("v", v, mu_x, mu_y)
    return a[:, 0] + np.hypot(mx * a[:, 1], my * a[:, 2]) <= tol * _row_norms(a)


def modified_velocity(u, mu_x, mu_y) -> np.ndarray:
    """De Saxcé modified velocity ``(u_n + ||M u_t||, u_t)``, shape (n, 3)."""
    a, mx, my = _prepare("u", u, mu_x, mu_y)
    return _modified(a, mx, my)


def _modified(a, mx, my) -> np.ndarray:
    """:func:`modified_velocity` for checked input (see :func:`_project`)."""
    out = a.copy()
    out[:, 0] += np.hypot(mx * a[:, 1], my * a[:, 2])
    return out


def project_elliptic_cone(tau, mu_x, mu_y) -> np.ndarray:
    """Euclidean projection of ``tau`` onto the elliptic cone ``K_mu`` (sect. 5).

    Parameters
    ----------
    tau : array_like, shape (n_contacts, 3) or (3,)
        Points ``(tau_n, tau_tx, tau_ty)`` in the local frames.
    mu_x, mu_y : float or array_like, shape (n_contacts,)
        Friction coefficients along ``t_x`` and ``t_y`` (>= 0).

    Returns
    -------
    r : ndarray, shape (n_contacts, 3)
        ``tau`` if it lies in ``K_mu``; 0 if it lies in the polar cone; otherwise
        the nearest point on the cone boundary.

    Raises
    ------
    ValueError
        Wrong shape, non-finite entries or negative coefficients.
    """
    a, mx, my = _prepare("tau", tau, mu_x, mu_y)
    return _project(a, mx, my)


def _project(a, mx, my) -> np.ndarray:
    """:func:`project_elliptic_cone` for checked input: ``a`` finite, shape (n, 3);
    ``mx``, ``my`` finite, >= 0, shape (n,).  The solvers' inner loops call this
    tens of times per Newton iteration; compiled, it costs 8 us for the 81
    contacts of a planning mesh, where the same algorithm vectorised over the
    contacts in numpy cost 280 us (numpy calls, not arithmetic)."""
    return _project_kernel(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(mx, dtype=float),
                           np.ascontiguousarray(my, dtype=float))


def local_frame(angle) -> np.ndarray:
    """Rotation(s) from world ``(x, y, z)`` to the local contact basis ``(n, t_x, t_y)``.

    The orthotropy axes are turned by ``angle`` (rad) counter-clockwise from world
    x, seen from +z: ``t_x = (cos a, sin a, 0)``, ``t_y = (-sin a, cos a, 0)``,
    ``n = e_z`` (sect. 3: ``mu_x`` acts along ``t_x``, ``mu_y`` along ``t_y``).
    The one implementation of the orthotropy frame: the FE step, the conversions
    below and ``pushplan``'s reduced model all use it.

    Parameters
    ----------
    angle : float or array_like, shape (n,)
        Orthotropy angle(s), rad.

    Returns
    -------
    T : ndarray, shape (3, 3), or (n, 3, 3) for an array of angles
        ``v_local = T @ v_world``; rows are ``n``, ``t_x``, ``t_y``.  Its block
        ``T[1:, :2].T`` maps local tangent coordinates to world ``(x, y)``.
    """
    th = np.asarray(angle, dtype=float)
    if not np.all(np.isfinite(th)):
        raise ValueError(f"angle must be finite, got {angle}")
    # a scalar through math, as the FE model always computed it (bit-identical results)
    c, s = (np.cos(th), np.sin(th)) if th.ndim else (np.float64(math.cos(th)), np.float64(math.sin(th)))
    zero, one = np.zeros_like(th), np.ones_like(th)
    rows = [np.stack(r, -1) for r in ((zero, zero, one), (c, s, zero), (-s, c, zero))]
    return np.stack(rows, -2)


def frame_derivative(angle: float) -> np.ndarray:
    """``dT/d angle`` (3, 3), 1/rad, of :func:`local_frame`'s ``T`` (rows ``n``,
    ``t_x``, ``t_y``): the friction-angle term of the sensitivities."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[0.0, 0.0, 0.0], [-s, c, 0.0], [-c, -s, 0.0]])


def to_local(v_world, angle) -> np.ndarray:
    """World ``(x, y, z)`` vectors, shape (n, 3), to local ``(n, t_x, t_y)``."""
    v = _as_contacts("v_world", v_world)
    return np.einsum("...ij,...j->...i", local_frame(angle), v)


def to_global(v_local, angle) -> np.ndarray:
    """Local ``(n, t_x, t_y)`` vectors, shape (n, 3), to world ``(x, y, z)``."""
    v = _as_contacts("v_local", v_local)
    return np.einsum("...ji,...j->...i", local_frame(angle), v)


def scaling_diagonal(mu_x, mu_y) -> tuple[np.ndarray, np.ndarray]:
    """The local solvers' change of variables to an isotropic cone, per contact.

    With ``mu = max(mu_x, mu_y)`` and ``D = diag(1, mu_x / mu, mu_y / mu)``,
    ``r = D s`` maps the isotropic cone ``||s_t|| <= mu s_n`` onto ``K_mu`` (eq. 15),
    so ``FC(W, q, M)`` is the isotropic ``FC(D W D, D q, mu)`` (the form Siconos'
    Alart-Curnier solver takes).  An isotropic contact keeps ``D = I`` and its
    own ``mu``: scaling it to the unit cone (``D = diag(1, mu, mu)``) would
    multiply its tangential flexibility by ``mu^2`` against the normal one, a
    condition number of 1e6 at ``mu = 1000``.  A frictionless contact keeps
    ``D = I`` and ``mu = 0``.

    Parameters
    ----------
    mu_x, mu_y : ndarray, shape (n,)
        Friction coefficients (>= 0); ``mu_y`` may be a scalar.

    Returns
    -------
    D : ndarray, shape (n, 3)
        The diagonals, dimensionless.
    mu : ndarray, shape (n,)
        Coefficient of each isotropic cone.
    """
    mx, my = _as_coefficients(mu_x, mu_y, np.shape(mu_x)[0] if np.ndim(mu_x) else 1)
    mu = np.maximum(mx, my)
    frictionless = mu == 0
    safe = np.where(frictionless, 1.0, mu)
    D = np.column_stack([np.ones(mu.shape[0]), np.where(frictionless, 1.0, mx / safe),
                         np.where(frictionless, 1.0, my / safe)])
    return D, mu
