"""The uncertainty of a predicted pose, propagated from an identification's covariance.

For commands run on the identified scenario, the lower-face pose ``q = (x, y, yaw)``
(m, m, rad) at rest after the scenario's ``[release]`` (the loaded pose without one)
depends on the identified parameters ``theta``; to first order

    Cov(q) = G C G^T,     G = dq/dtheta  (3, p),

with ``C`` the reported covariance of :mod:`.uncertainty` and ``G`` by forward
differences of FE rollouts (the steps of :data:`.fit.FD_STEP`), one rollout per
parameter.  Parameters with an infinite standard deviation (not determined by the
data) are left out and named: their uncertainty is not bounded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config.scenario import Scenario
from ..run import drive
from .fit import FD_STEP
from .forward import IdentificationError, with_parameters


@dataclass(frozen=True)
class PosePrediction:
    """A predicted pose ``(x, y, yaw)`` (m, m, rad), its covariance (3, 3) and the
    parameters the covariance leaves out (not determined)."""

    pose: np.ndarray
    covariance: np.ndarray
    left_out: tuple[str, ...]
    state: str

    @property
    def sigma(self) -> np.ndarray:
        """(3,) standard deviations, m, m, rad."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def to_dict(self) -> dict:
        s = self.sigma
        return {"state": self.state, "pose": [float(self.pose[0]), float(self.pose[1]), math.degrees(self.pose[2])],
                "sigma": [float(s[0]), float(s[1]), math.degrees(s[2])], "units": "m, m, deg",
                "left_out": list(self.left_out)}


def _pose(scenario: Scenario, names, theta, commands) -> np.ndarray:
    sc = with_parameters(scenario, names, theta)
    run = drive(sc.model(), tuple(commands), release=sc.release)
    if not run.completed:
        f = run.summary.failure
        raise IdentificationError(f"FE rollout for the pose prediction failed at step {f.step} ({f.status}): "
                                  f"{f.message}")
    if run.summary.rest is not None:
        r = run.summary.rest
        return np.array([r.lower_centroid[0], r.lower_centroid[1], r.lower_yaw])
    s = run.summary.steps[-1]
    return np.array([s.lower_centroid[0], s.lower_centroid[1], s.lower_yaw])


def predicted_pose(scenario: Scenario, commands, names, estimate, covariance) -> PosePrediction:
    """The pose after ``commands`` (the press included) on ``scenario`` with the parameters
    ``names`` at ``estimate`` (p,), and its covariance from theirs ``covariance`` (p, p)
    (module docstring; :func:`.document.covariance_from_document` reads it from an
    ``identified.json``).

    Raises
    ------
    IdentificationError
        An FE rollout failed.
    """
    names, theta, C = tuple(names), np.asarray(estimate, float), np.asarray(covariance, float)
    q0 = _pose(scenario, names, theta, commands)
    keep = [j for j in range(len(names)) if math.isfinite(C[j, j])]
    G = np.zeros((3, len(keep)))
    for col, j in enumerate(keep):
        h = FD_STEP[names[j]] * (abs(theta[j]) if names[j] == "young" else 1.0)
        t = theta.copy()
        t[j] += h
        G[:, col] = (_pose(scenario, names, t, commands) - q0) / h
    cov = G @ C[np.ix_(keep, keep)] @ G.T
    return PosePrediction(q0, cov, tuple(k for j, k in enumerate(names) if j not in keep),
                          "rest" if scenario.release is not None else "loaded")
