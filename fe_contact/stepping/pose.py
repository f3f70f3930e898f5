"""Rigid-body summaries of a deformed face: centroid displacement, best-fit yaw,
and the twist between the upper and lower faces."""

from __future__ import annotations

import numpy as np

ZERO_MOTION = 1e-12
"""In-plane displacement (relative to the face size) below which a direction is undefined."""


def face_centroid_displacement(displacement: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Area-weighted mean displacement of a face.

    Parameters
    ----------
    displacement : ndarray, shape (n, 3)
        Nodal displacements of the face nodes, m.
    weights : ndarray, shape (n,)
        Tributary areas (any positive weights), m^2.

    Returns
    -------
    ndarray, shape (3,)
    """
    w = np.asarray(weights, dtype=float)
    return (w[:, None] * displacement).sum(axis=0) / w.sum()


def planar_yaw(reference: np.ndarray, current: np.ndarray, weights: np.ndarray) -> float:
    """Best-fit (weighted least squares, 2D Kabsch) rotation about z taking the
    reference in-plane positions to the current ones.

    Parameters
    ----------
    reference, current : ndarray, shape (n, 2) or (n, 3)
        Node positions; only x, y are used, m.
    weights : ndarray, shape (n,)

    Returns
    -------
    float
        Yaw angle, rad, counter-clockwise seen from +z, in (-pi, pi].
    """
    w = np.asarray(weights, dtype=float)[:, None]
    p = np.asarray(reference, dtype=float)[:, :2]
    x = np.asarray(current, dtype=float)[:, :2]
    p = p - (w * p).sum(axis=0) / w.sum()
    x = x - (w * x).sum(axis=0) / w.sum()
    cross = (w[:, 0] * (p[:, 0] * x[:, 1] - p[:, 1] * x[:, 0])).sum()
    dot = (w[:, 0] * (p * x).sum(axis=1)).sum()
    return float(np.arctan2(cross, dot))


def twist_angle(upper: np.ndarray, lower: np.ndarray, scale: float) -> float:
    """Signed angle from the upper to the lower in-plane centroid displacement.

    Parameters
    ----------
    upper, lower : ndarray, shape (2,) or (3,)
        Cumulative centroid displacements, m (only x, y used).
    scale : float
        Length scale of the block, m; displacements shorter than
        ``ZERO_MOTION * scale`` have no direction and give a zero twist.

    Returns
    -------
    float
        rad, positive when the lower face moves counter-clockwise of the upper face.
    """
    a = np.asarray(upper, dtype=float)[:2]
    b = np.asarray(lower, dtype=float)[:2]
    tiny = ZERO_MOTION * scale
    if np.linalg.norm(a) <= tiny or np.linalg.norm(b) <= tiny:
        return 0.0
    return float(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))


def wrap_angle(angle):
    """``angle`` (rad, scalar or array) wrapped to ``[-pi, pi)``."""
    wrapped = (np.asarray(angle, dtype=float) + np.pi) % (2 * np.pi) - np.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped
