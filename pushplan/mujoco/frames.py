"""Rotations about the world vertical of MuJoCo bodies: matrices, quaternions
(w, x, y, z, MuJoCo's order) and the yaw of a body's rotation matrix.

The yaw and twist of a deformed *face* (point sets) are :mod:`fe_contact.stepping.pose`'s
``planar_yaw`` and ``twist_angle``; nothing here re-implements them.
"""

from __future__ import annotations

import math

import numpy as np


def rz(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (rad) about world z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_z(angle: float) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a rotation by ``angle`` (rad) about world z."""
    return np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a b`` of two (4,) quaternions (w, x, y, z): rotate by b, then a."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def matrix_yaw(R: np.ndarray) -> float:
    """Yaw (rad, in (-pi, pi]) of a (3, 3) rotation matrix: the angle of its x axis in the
    world x-y plane, ``atan2(R_yx, R_xx)``."""
    return float(math.atan2(R[1, 0], R[0, 0]))

