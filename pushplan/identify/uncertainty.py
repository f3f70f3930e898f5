"""Uncertainty that covers the truth when the model is not exact: the Gauss-Newton
covariance of :mod:`.fit` widened by the model's error and checked against the
chi-square surface itself.

With the whitened residual ``r = (y_FE - y_obs) / sigma`` at the estimate, its
Jacobian ``J`` (n, p) and ``C0 = (J^T J)^-1`` (parameter units), the reported
covariance is

    C = s2 C0' + d d^T,

* ``s2`` (the chi-square rule): the reduced chi-square ``chi2 / nu`` (``nu = n - p``)
  when it exceeds what the noise explains, ``1 + CHI2_SIGMAS sqrt(2 / nu)`` (the
  chi-square distribution's mean plus three of its standard deviations), else 1
  (the Birge ratio; e.g. Bevington & Robinson, *Data reduction and error analysis*,
  3rd ed., 2003, sec. 11.5): misfit the noise cannot explain is taken as model error
  spread like the noise;
* ``d`` (p,) the discretisation term: the FE predictions at the estimate on the
  scenario's mesh and on one refined ``REFINEMENT`` times in each direction give the
  error of the model mesh's prediction by Richardson's estimate (the mesh study of
  :mod:`pushplan.studies.richardson`, here from two meshes and an assumed order)

      e = SAFETY_FACTOR (y_h - y_h/r) r^p / (r^p - 1),   p = ASSUMED_ORDER,

  and the shift of the estimate it causes, ``d = -C0 J^T (e / sigma)`` (the
  least-squares estimate's linear response to an error ``e`` in the model);
* ``C0'`` is ``C0`` unless the chi-square surface disagrees with it: along the
  linearised profile path of parameter j, ``theta(t) = theta_hat + t C0[:, j] / sqrt(C0_jj)``
  (the other parameters re-optimised to first order), a linear model has
  ``chi2 - chi2_min = t^2``.  At ``t = +-2`` the actual increase is evaluated (two FE
  rollouts per parameter); below ``FLAT_RATIO * 4`` on either side
  (a non-smooth partial-slip push, a strongly nonlinear response) the ``t`` where it
  reaches 4 is searched on that side (doubling, then bisection) and the parameter's
  standard deviation becomes ``max(t_-, t_+) / 2 sqrt(C0_jj)`` (a profile-likelihood
  interval along the linearised path), its correlations kept.

The 95 % interval is ``theta_hat +- 1.96 sqrt(C_jj)``, its lower end at least 0 for the
coefficients and Young's modulus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SAFETY_FACTOR = 1.25
"""Roache's safety factor, the one of :mod:`pushplan.studies.richardson` (a layer this
one does not import)."""
CHI2_SIGMAS = 3.0
"""The reduced chi-square is inflating when above ``1 + CHI2_SIGMAS sqrt(2 / nu)``."""
REFINEMENT = 2
ASSUMED_ORDER = 2.0
"""Order of the hex8 displacement error (O(h^2)) assumed by the two-mesh estimate."""
FLAT_RATIO = 0.5
"""The linearised interval stands unless chi2 - chi2_min at t = +-2 is below this fraction
of 4 (a steeper surface keeps the wider, linearised interval)."""
PROFILE_T_MAX = 64.0
PROFILE_BISECTIONS = 4
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Uncertainty:
    """The reported uncertainty (parameter units; angles deg).

    ``sigma`` (p,) the reported standard deviations, ``interval`` (p, 2) the 95 % bounds,
    ``method`` per parameter ("linearised" or "profile"), ``covariance`` (p, p).
    """

    sigma: np.ndarray
    interval: np.ndarray
    method: tuple[str, ...]
    covariance: np.ndarray
    chi2_factor: float
    discretisation: np.ndarray
    discretisation_chi2: float | None
    profile_ratio: np.ndarray
    warnings: tuple[str, ...] = field(default=())
    fe_rollouts: int = 0

    def to_dict(self, names) -> dict:
        return {
            "covariance_rule": "C = s2 * C0' + d d^T (pushplan.identify.uncertainty)",
            "chi2_factor_s2": self.chi2_factor,
            "discretisation_shift": {k: float(v) for k, v in zip(names, self.discretisation, strict=True)},
            "discretisation_chi2": self.discretisation_chi2,
            "profile_check": {k: [_finite(v) for v in r] for k, r in zip(names, self.profile_ratio, strict=True)},
            "warnings": list(self.warnings), "fe_rollouts": self.fe_rollouts,
        }


def _finite(v):
    return float(v) if math.isfinite(v) else None


def chi2_factor(chi2: float, dof: int) -> float:
    """``s2`` of the module docstring."""
    if dof <= 0:
        return 1.0
    reduced = chi2 / dof
    return reduced if reduced > 1.0 + CHI2_SIGMAS * math.sqrt(2.0 / dof) else 1.0


def discretisation_shift(J, sigma, y_h, y_fine, C0):
    """``(d, ||e / sigma||^2)`` of the module docstring from the predictions on the model
    mesh ``y_h`` and the refined one ``y_fine`` (n,)."""
    rp = REFINEMENT**ASSUMED_ORDER
    e = SAFETY_FACTOR * (y_h - y_fine) * rp / (rp - 1.0)
    ew = e / sigma
    return -C0 @ (J.T @ ew), float(ew @ ew)


def _profile_side(chi2_at, theta, step, chi2_min, sign) -> tuple[float, float]:
    """``(ratio, t)``: the increase at ``t = 2`` over 4, and the ``t`` where it reaches 4
    (2 when the ratio is at least :data:`FLAT_RATIO`)."""
    rise = max(chi2_at(theta + sign * 2.0 * step) - chi2_min, 0.0)
    ratio = rise / 4.0
    if ratio >= FLAT_RATIO:  # as steep as linear or steeper: the linearised interval stands
        return ratio, 2.0
    lo, hi = 2.0, 4.0
    while hi < PROFILE_T_MAX and chi2_at(theta + sign * hi * step) - chi2_min < 4.0:
        lo, hi = hi, 2.0 * hi
    for _ in range(PROFILE_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2_at(theta + sign * mid * step) - chi2_min < 4.0 else (lo, mid)
    return ratio, 0.5 * (lo + hi)


def profile_sigmas(chi2_at, theta, C0, chi2_min, free):
    """Per parameter: the two-sided ratios (p, 2) and the standard deviation along the
    linearised profile path (p,), ``sqrt(C0_jj)`` where it is linear; ``free`` marks the
    parameters to check (the others keep their linearised value)."""
    p = len(theta)
    ratios = np.full((p, 2), np.nan)
    sd0 = np.sqrt(np.maximum(np.diag(C0), 0.0))
    sd = sd0.copy()
    for j in range(p):
        if not free[j] or not (math.isfinite(sd0[j]) and sd0[j] > 0):
            continue
        step = C0[:, j] / sd0[j]
        sides = [_profile_side(chi2_at, theta, step, chi2_min, s) for s in (-1.0, 1.0)]
        ratios[j] = [r for r, _ in sides]
        sd[j] = sd0[j] * max(t for _, t in sides) / 2.0
    return ratios, sd


def combine(names, theta, C0, s2, shift, sd_profile, ratios) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """``(covariance, interval (p, 2), method)`` of the module docstring."""
    sd0 = np.sqrt(np.maximum(np.diag(C0), 0.0))
    scale = np.where(sd0 > 0, sd_profile / np.where(sd0 > 0, sd0, 1.0), 1.0)
    C = s2 * (C0 * np.outer(scale, scale)) + np.outer(shift, shift)
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    interval = np.column_stack([theta - Z95 * sd, theta + Z95 * sd])
    positive = np.array([k != "angle_deg" for k in names])  # friction coefficients and moduli are > 0
    interval[positive, 0] = np.maximum(interval[positive, 0], 0.0)
    method = tuple("profile" if np.isfinite(r).all() and min(r) < FLAT_RATIO else "linearised" for r in ratios)
    return C, interval, method


def chi2_warning(chi2: float, dof: int, s2: float, mesh_chi2: float | None) -> str | None:
    """A warning naming the likely causes when the reduced chi-square is far above 1."""
    if s2 <= 1.0:
        return None
    reduced = chi2 / dof
    mesh = ("the discretisation error estimated from a refined mesh accounts for chi2 ~ "
            f"{mesh_chi2:.3g} of {chi2:.3g}" if mesh_chi2 is not None else "the mesh error was not estimated")
    return (f"reduced chi2 = {reduced:.3g} is far above 1 (the noise explains up to "
            f"{1 + CHI2_SIGMAS * math.sqrt(2 / dof):.3g}); likely causes: a mesh too coarse for the data ({mesh}; "
            "try a finer [block] elements), a stiffness unlike the block's (try --fit young), or noise levels "
            "below the real ones (check --pose-noise, --force-noise, --force-noise-rel); the sigmas are "
            f"inflated by sqrt({reduced:.3g})")
