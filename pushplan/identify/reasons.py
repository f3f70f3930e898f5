"""Whether each parameter is identifiable from the observations, and why not.

The flag is statistical (:mod:`.fit`: a finite standard deviation below a limit);
the reason names the cause a user can act on, from the pushes' geometry in the
orthotropy frame: a slip along one axis of the friction ellipse loads only that
axis's coefficient (``g = N R M^2 R^T s / ||M R^T s||`` with ``R^T s = (1, 0)`` gives
``g = N mu_x t_x``, whatever ``mu_y``); no sliding push gives no coefficient at all;
an ellipse that is nearly a circle has no axis.
"""

from __future__ import annotations

import math

import numpy as np

from ..config.observations import Observations
from .prefit import sliding_rows, slip_directions

REL_SIGMA_LIMIT = 0.1
"""A coefficient (or Young's modulus) is identifiable when sigma < 10 % of its value."""
ANGLE_SIGMA_LIMIT_DEG = 5.0
"""The orthotropy angle is identifiable when sigma < 5 deg."""
AXIS_CONE_DEG = 10.0
"""Pushes within this angle of an orthotropy axis count as along it."""
ISOTROPY_REL = 0.05
ANISOTROPY_SIGMAS = 3.0
"""The orthotropy angle is identifiable only when ``|mu_x - mu_y|`` exceeds this many of
its standard deviations ``sqrt(V_xx + V_yy - 2 V_xy)``: data that cannot tell the two
coefficients apart have no axis, however small the angle's own sigma came out."""


def push_directions(obs, pose_noise: float) -> np.ndarray:
    """Unit in-plane slip directions of the sliding rows (from the pose when observed,
    else the in-plane commands), (n, 2), of one observation file or several."""
    if not isinstance(obs, Observations):
        return np.vstack([np.zeros((0, 2))] + [push_directions(o, pose_noise) for o in obs])
    rows = sliding_rows(obs, pose_noise)
    if len(rows):
        return slip_directions(obs, rows)
    if "lower_x" in obs.values:
        return np.zeros((0, 2))
    d = np.array([[c.dx, c.dy] for c in obs.commands if c.dx or c.dy]).reshape(-1, 2)
    return d / np.linalg.norm(d, axis=1, keepdims=True) if len(d) else d


def _axis_spread(directions: np.ndarray, angle_deg: float) -> tuple[float, float]:
    """Largest angle (deg) of the directions from the t_x line and from the t_y line."""
    a = math.radians(angle_deg)
    local = directions @ np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    from_x = np.degrees(np.arcsin(np.clip(np.abs(local[:, 1]), 0, 1)))
    return float(from_x.max()), float((90.0 - from_x).max())


def _cause(name: str, values: dict, directions: np.ndarray) -> str:
    if not len(directions):
        return "no observed push makes the lower face slide, so the force only bounds the friction from below"
    if name in ("mu_x", "mu_y", "angle_deg") and "angle_deg" in values:
        off_x, off_y = _axis_spread(directions, values["angle_deg"])
        axis = f"orthotropy axis t_x at {values['angle_deg']:.3g} deg"
        if name == "mu_y" and off_x < AXIS_CONE_DEG:
            return (f"every sliding push is along the {axis} (within {off_x:.2g} deg): the force then "
                    "depends on mu_x only; push across the axis")
        if name == "mu_x" and off_y < AXIS_CONE_DEG:
            return (f"every sliding push is along t_y (within {off_y:.2g} deg of the {axis} + 90 deg): the force "
                    "then depends on mu_y only; push across the axis")
    if name == "angle_deg" and {"mu_x", "mu_y"} <= set(values):
        mx, my = values["mu_x"], values["mu_y"]
        if abs(mx - my) < ISOTROPY_REL * max(mx, my):
            return f"mu_x = {mx:.4g} and mu_y = {my:.4g} nearly agree: a nearly circular ellipse has no axis"
    return "the observations barely depend on it; more pushes in other directions would help"


def anisotropy(names, theta, cov) -> tuple[float, float] | None:
    """``(mu_x - mu_y, its standard deviation)`` from the covariance, or None."""
    if cov is None or not {"mu_x", "mu_y"} <= set(names):
        return None
    i, j = names.index("mu_x"), names.index("mu_y")
    var = cov[i, i] + cov[j, j] - 2.0 * cov[i, j]
    return float(theta[i] - theta[j]), math.sqrt(max(var, 0.0))


def identifiability(names, theta, sigma, obs, pose_noise: float, cov=None):
    """``(flags, reasons)``: a flag per parameter and, for each unidentifiable one, why
    (``cov`` the covariance, for the anisotropy test of the angle)."""
    values = dict(zip(names, (float(t) for t in theta), strict=True))
    directions = push_directions(obs, pose_noise)
    flags, reasons = [], {}
    aniso = anisotropy(tuple(names), theta, cov)
    for k, v, s in zip(names, theta, sigma, strict=True):
        if k == "angle_deg" and aniso is not None and not abs(aniso[0]) > ANISOTROPY_SIGMAS * aniso[1]:
            flags.append(False)
            reasons[k] = (f"mu_x - mu_y = {aniso[0]:.3g} +- {aniso[1]:.2g} is within {ANISOTROPY_SIGMAS:g} sigma of 0: "
                          "the data do not tell the two coefficients apart, so the ellipse has no axis to orient")
            continue
        if k == "angle_deg":
            ok = math.isfinite(s) and s < ANGLE_SIGMA_LIMIT_DEG
            size = f"{s:.3g} deg (limit {ANGLE_SIGMA_LIMIT_DEG:g} deg)"
        else:
            ok = math.isfinite(s) and s < REL_SIGMA_LIMIT * abs(v)
            size = f"{100 * s / abs(v):.3g} % of the value (limit {100 * REL_SIGMA_LIMIT:g} %)"
        flags.append(bool(ok))
        if not ok:
            what = "not determined (a null direction of the Jacobian)" if not math.isfinite(s) else (
                f"standard deviation {size}")
            reasons[k] = f"{what}: {_cause(k, values, directions)}"
    return tuple(flags), reasons
