"""Reference 8-node hexahedron: trilinear shape functions and Gauss quadrature.

The reference cell is ``[-1, 1]^3``; local nodes follow VTK_HEXAHEDRON ordering
(bottom face ``xi_3 = -1`` counter-clockwise seen from +xi_3, then the top face).
"""

from __future__ import annotations

from numbers import Integral

import numpy as np

__all__ = ["HEX8_CORNERS", "gauss_hex", "hex8_shape", "hex8_grad"]

#: Reference coordinates of the 8 local nodes, shape (8, 3).
HEX8_CORNERS = np.array(
    [
        [-1.0, -1.0, -1.0],
        [1.0, -1.0, -1.0],
        [1.0, 1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
        [1.0, -1.0, 1.0],
        [1.0, 1.0, 1.0],
        [-1.0, 1.0, 1.0],
    ]
)
HEX8_CORNERS.setflags(write=False)

_MAX_ORDER = 10


def gauss_hex(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor-product Gauss-Legendre rule on ``[-1, 1]^3``.

    Parameters
    ----------
    order : int
        Points per direction, 1 to 10 (2 -> 8 points, 3 -> 27 points). The rule
        integrates polynomials of degree ``2*order - 1`` per direction exactly.

    Returns
    -------
    points : ndarray, shape (order**3, 3)
        Quadrature points, first coordinate fastest.
    weights : ndarray, shape (order**3,)
        Weights, summing to 8 (the reference volume).

    Raises
    ------
    ValueError
        If ``order`` is not an integer in ``[1, 10]``.
    """
    if isinstance(order, bool) or not isinstance(order, Integral) or not 1 <= order <= _MAX_ORDER:
        raise ValueError(f"order must be an integer in [1, {_MAX_ORDER}], got {order!r}")
    x, w = np.polynomial.legendre.leggauss(int(order))
    z3, y3, x3 = np.meshgrid(x, x, x, indexing="ij")
    points = np.stack([x3.ravel(), y3.ravel(), z3.ravel()], axis=-1)
    weights = np.einsum("k,j,i->kji", w, w, w).ravel()
    return points, weights


def _as_points(xi) -> np.ndarray:
    xi = np.asarray(xi, dtype=np.float64)
    if xi.ndim == 1:
        xi = xi[None, :]
    if xi.ndim != 2 or xi.shape[1] != 3:
        raise ValueError(f"xi must have shape (Q, 3) or (3,), got {np.shape(xi)}")
    return xi


def hex8_shape(xi) -> np.ndarray:
    """Trilinear shape functions ``N_a(xi) = prod_d (1 + s_ad xi_d) / 8``.

    Parameters
    ----------
    xi : array_like, shape (Q, 3) or (3,)
        Reference points.

    Returns
    -------
    ndarray, shape (Q, 8)
    """
    xi = _as_points(xi)
    return np.prod(1.0 + xi[:, None, :] * HEX8_CORNERS[None, :, :], axis=-1) / 8.0


def hex8_grad(xi) -> np.ndarray:
    """Reference gradients ``dN_a / dxi_d`` of the trilinear shape functions.

    Parameters
    ----------
    xi : array_like, shape (Q, 3) or (3,)
        Reference points.

    Returns
    -------
    ndarray, shape (Q, 8, 3)
    """
    xi = _as_points(xi)
    factors = 1.0 + xi[:, None, :] * HEX8_CORNERS[None, :, :]  # (Q, 8, 3)
    grad = np.empty(factors.shape)
    for d in range(3):
        others = [e for e in range(3) if e != d]
        grad[..., d] = HEX8_CORNERS[:, d] * factors[..., others[0]] * factors[..., others[1]]
    return grad / 8.0
