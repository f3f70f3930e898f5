"""The identified parameter distribution a robust plan holds under: its sigma points, its
samples, the probability that a Gaussian final pose lands within tolerance, and the
binomial interval of a Monte Carlo fraction.

The distribution is Gaussian, ``theta ~ N(theta_hat, C)`` over the identified scenario
fields (``mu_x``, ``mu_y``, ``angle_deg`` in degrees, ``young`` in Pa), as
``identified.json`` reports them (:func:`pushplan.identify.document.covariance_from_document`).

Sigma points (the unscented transform; Julier & Uhlmann, Proc. IEEE 92(3), 2004): with
``n`` parameters, ``L L^T = C`` and ``kappa`` = :data:`KAPPA`,

    theta_0 = theta_hat,   theta_{+-j} = theta_hat +- sqrt(n + kappa) L[:, j],
    w_0 = kappa / (n + kappa),   w_{+-j} = 1 / (2 (n + kappa)),

``2 n + 1`` points whose weighted mean and covariance are ``theta_hat`` and ``C``; a map
``p(theta)`` linear in theta has the same mean and covariance from them, a quadratic one
the same mean.  All weights are positive (``kappa > 0``), so the robust objective is a
sum of squares.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..config.plan import PlanSpec
from ..config.scenario import Scenario

KAPPA = 1.0
"""The sigma points' spread ``sqrt(n + kappa)`` standard deviations (2 for three parameters)."""
POSITIVE = ("mu_x", "mu_y", "young")
"""Parameters a truth must have > 0 (a draw with one <= 0 is redrawn)."""
QMC_POINTS = 2**14
"""Scrambled Sobol points of :func:`success_probability` (its error ~ 1e-3, stated in docs/planning.md)."""
QMC_SEED = 12345
FACTOR_RTOL = 1e-9
"""How closely :meth:`Distribution.factor`'s ``L L^T`` must give ``C``, relative to each pair's standard deviations."""
MAX_REDRAWS = 10
"""Draws per truth before :meth:`Distribution.sample` gives up on a distribution mostly at mu <= 0."""


@dataclass(frozen=True)
class Distribution:
    """``N(mean, covariance)`` over the scenario fields ``names`` (angles in degrees)."""

    names: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        p = len(self.names)
        if np.shape(self.mean) != (p,) or np.shape(self.covariance) != (p, p):
            raise ValueError(f"distribution: mean {np.shape(self.mean)} / covariance {np.shape(self.covariance)} "
                             f"for {p} parameters")
        if not (np.isfinite(self.mean).all() and np.isfinite(self.covariance).all()):
            raise ValueError("distribution: mean and covariance must be finite (an undetermined parameter?)")

    @property
    def zero(self) -> bool:
        """Whether the covariance is zero (a point: the nominal plan's view)."""
        return not np.any(self.covariance)

    def factor(self) -> np.ndarray:
        """``L`` (p, p) with ``L L^T = C``: ``V Lambda^(1/2)`` of the symmetric
        eigen-decomposition of ``C`` (C may be singular), the covariance's principal axes.
        Where that misses ``C`` by more than :data:`FACTOR_RTOL` of a pair's standard
        deviations (eigh's rounding is relative to the largest eigenvalue: a modulus in Pa
        beside a friction coefficient), ``D V' Lambda'^(1/2)`` of the correlation
        ``D^-1 C D^-1`` instead, ``D`` the standard deviations."""
        C = 0.5 * (self.covariance + self.covariance.T)
        lam, V = np.linalg.eigh(C)
        L = V * np.sqrt(np.maximum(lam, 0.0))
        d = np.sqrt(np.maximum(np.diag(C), 0.0))
        if np.all(np.abs(L @ L.T - C) <= FACTOR_RTOL * np.outer(d, d)):
            return L
        inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        lam, V = np.linalg.eigh(C * np.outer(inv, inv))
        return d[:, None] * V * np.sqrt(np.maximum(lam, 0.0))

    def sigma_points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(points (S, p), weights (S,))`` of the module docstring; the mean alone (S = 1)
        for a zero covariance."""
        if self.zero:
            return self.mean[None, :].copy(), np.ones(1)
        n = len(self.names)
        spread = math.sqrt(n + KAPPA) * self.factor()
        points = np.vstack([self.mean, self.mean + spread.T, self.mean - spread.T])
        weights = np.concatenate([[KAPPA / (n + KAPPA)], np.full(2 * n, 0.5 / (n + KAPPA))])
        return points, weights

    def sample(self, count: int, rng: np.random.Generator) -> tuple[np.ndarray, int]:
        """``(truths (count, p), redrawn)``: draws with every :data:`POSITIVE` parameter > 0
        (a draw outside is redrawn, ``redrawn`` counts them).

        Raises
        ------
        ValueError
            More than ``MAX_REDRAWS * count`` draws outside.
        """
        L = self.factor()
        positive = np.array([k in POSITIVE for k in self.names])
        out, redrawn = [], 0
        while len(out) < count:
            theta = self.mean + L @ rng.standard_normal(len(self.names))
            if np.any(theta[positive] <= 0):
                redrawn += 1
                if redrawn > MAX_REDRAWS * max(count, 1):
                    raise ValueError("distribution: most draws have a friction coefficient or modulus <= 0")
                continue
            out.append(theta)
        return np.array(out).reshape(count, len(self.names)), redrawn

    def scenario(self, scenario: Scenario, theta) -> Scenario:
        """``scenario`` with the parameters set to ``theta``."""
        return dataclasses.replace(scenario, **{k: float(v) for k, v in zip(self.names, theta, strict=True)})

    def to_dict(self) -> dict:
        return {"parameters": list(self.names), "mean": [float(v) for v in self.mean],
                "covariance": [[float(v) for v in row] for row in self.covariance]}


def pose_moments(finals: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (3,) and covariance (3, 3) of final poses (S, 3) at the sigma points."""
    mean = weights @ finals
    dev = finals - mean
    return mean, (weights[:, None] * dev).T @ dev


def success_probability(mean, covariance, spec: PlanSpec) -> float:
    """``P(|p_xy - x*| <= tol and |yaw - yaw*| <= yaw_tol)`` for a final pose
    ``p ~ N(mean, covariance)`` (the yaw condition only with a yaw target), by
    :data:`QMC_POINTS` scrambled Sobol points (a fixed seed: the same number for the same
    moments; exactly the indicator of ``mean`` for a zero covariance)."""
    from scipy.stats import norm, qmc

    u = qmc.Sobol(3, scramble=True, seed=QMC_SEED).random(QMC_POINTS)
    z = norm.ppf(np.clip(u, 1e-12, 1 - 1e-12))
    lam, V = np.linalg.eigh(0.5 * (np.asarray(covariance) + np.asarray(covariance).T))
    p = np.asarray(mean, float) + z @ (V * np.sqrt(np.maximum(lam, 0.0))).T
    ok = np.hypot(p[:, 0] - spec.target[0], p[:, 1] - spec.target[1]) <= spec.tolerance
    if spec.yaw_targeted:
        yaw = np.angle(np.exp(1j * (p[:, 2] - spec.target[2])))
        ok &= np.abs(yaw) <= spec.yaw_tolerance
    return float(ok.mean())


def binomial_interval(successes: int, count: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Clopper-Pearson (exact) interval of a binomial proportion
    (:meth:`scipy.stats.binomtest` ``proportion_ci``); ``(0, 1)`` for no trials."""
    if count == 0:
        return 0.0, 1.0
    from scipy.stats import binomtest

    ci = binomtest(successes, count).proportion_ci(confidence, method="exact")
    return float(ci.low), float(ci.high)
