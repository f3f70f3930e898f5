"""The reduced-model estimate that starts the FE fit: the elliptic limit surface of
:mod:`pushplan.planning.reduced_model` with associated slip.

While the lower face slides, the drive force ``g`` (minus the tangential force on the
gripper) is on the limit surface and the slip increment ``s`` is along its normal
(paper eq. 23-30, summed over the face):

    g = N R M^2 R^T s / ||M R^T s||,     M = diag(mu_x, mu_y),  R = fe_contact.local_frame(angle)[1:, :2]^T,

with ``N`` the normal force (``force_z``).  Each sliding row gives two equations in
``(mu_x, mu_y, angle)``; they are solved by least squares (no FE rollout).  The
partial slip of the FE block (the face does not slide as one body) is what the FE
fit then corrects.
"""

from __future__ import annotations

import math

import numpy as np

from fe_contact import local_frame

from ..config.observations import Observations

PREFIT_COLUMNS = ("lower_x", "lower_y", "force_x", "force_y", "force_z")
SLIDING_FRACTION = 0.3
"""A row slides when its lower-face increment exceeds this fraction of the command's
in-plane length (and ten pose noises)."""


def sliding_rows(obs: Observations, pose_noise: float) -> np.ndarray:
    """Indices of rows whose lower face slides (needs ``lower_x``, ``lower_y``)."""
    if "lower_x" not in obs.values or "lower_y" not in obs.values:
        return np.zeros(0, int)
    p = np.stack([obs.values["lower_x"], obs.values["lower_y"]], axis=1)
    dp = np.diff(np.vstack([np.zeros(2), p]), axis=0)
    cmd = np.array([math.hypot(c.dx, c.dy) for c in obs.commands])
    moved = np.linalg.norm(dp, axis=1)
    return np.flatnonzero((moved > SLIDING_FRACTION * cmd) & (moved > 10 * pose_noise) & (cmd > 0))


def slip_directions(obs: Observations, rows) -> np.ndarray:
    """Unit lower-face increments of ``rows``, (n, 2)."""
    p = np.stack([obs.values["lower_x"], obs.values["lower_y"]], axis=1)
    dp = np.diff(np.vstack([np.zeros(2), p]), axis=0)[rows]
    return dp / np.linalg.norm(dp, axis=1, keepdims=True)


def limit_force(theta, s: np.ndarray) -> np.ndarray:
    """``g / N`` for slip directions ``s`` (n, 2) and ``theta = (mu_x, mu_y, angle_deg)``."""
    mu_x, mu_y, angle = theta[0], theta[1], math.radians(theta[2])
    R = local_frame(angle)[1:, :2].T  # orthotropy (t_x, t_y) -> world (x, y)
    m = np.array([mu_x, mu_y])
    local = s @ R  # rows R^T s
    return (m**2 * local) @ R.T / np.linalg.norm(m * local, axis=1, keepdims=True)


def _sliding_forces(obs: Observations, pose_noise: float):
    """Slip directions (n, 2) and drive forces per normal force (n, 2) of the sliding rows."""
    if any(k not in obs.values for k in PREFIT_COLUMNS):
        return np.zeros((0, 2)), np.zeros((0, 2))
    rows = sliding_rows(obs, pose_noise)
    g = np.stack([obs.values["force_x"][rows], obs.values["force_y"][rows]], axis=1)  # the drive force on the block
    return slip_directions(obs, rows), g / -obs.values["force_z"][rows, None]


def prefit(obs, theta0, pose_noise: float):
    """``(mu_x, mu_y, angle_deg)`` from the sliding rows of one observation file or
    several, or None when they lack the columns or have fewer than two sliding rows."""
    from scipy.optimize import least_squares

    files = (obs,) if isinstance(obs, Observations) else tuple(obs)
    pairs = [_sliding_forces(o, pose_noise) for o in files]
    s, g = np.vstack([p[0] for p in pairs]), np.vstack([p[1] for p in pairs])
    if len(s) < 2:
        return None

    def residual(theta):
        return (limit_force(theta, s) - g).ravel()

    lo, hi = [1e-4, 1e-4, -np.inf], [np.inf, np.inf, np.inf]
    start = np.clip(np.asarray(theta0, float), np.array(lo) * 1.01, hi)
    sol = least_squares(residual, start, bounds=(lo, hi), x_scale=[0.1, 0.1, 10.0])
    return same_labels(sol.x, theta0[2])


def nearest_angle(angle_deg: float, reference_deg: float) -> float:
    """``angle_deg`` modulo 180 deg (an axis is a line), within 90 deg of ``reference_deg``."""
    return reference_deg + 0.0 - ((reference_deg - angle_deg + 90.0) % 180.0 - 90.0)


def same_labels(theta, reference_deg: float) -> np.ndarray:
    """The ellipse ``(mu_x, mu_y, angle)`` is also ``(mu_y, mu_x, angle + 90)``: the form
    whose t_x axis is nearer the reference angle (the scenario's labelling)."""
    mu_x, mu_y, angle = (float(v) for v in theta)
    a, b = nearest_angle(angle, reference_deg), nearest_angle(angle + 90.0, reference_deg)
    return np.array([mu_x, mu_y, a]) if abs(a - reference_deg) <= abs(b - reference_deg) else np.array([mu_y, mu_x, b])
