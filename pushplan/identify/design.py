"""Experiment design: N push directions that make ``(mu_x, mu_y, angle)`` identifiable.

Sensitivities of the reduced model: a sliding push along ``s`` transmits the force of
:func:`~.prefit.limit_force`, ``g(s) = N R M^2 R^T s / ||M R^T s||``; its derivative
``G(s) = dg/dtheta`` (2 x 3, central differences of the closed form, no FE) over the
force noise is the Fisher information ``G^T G / sigma^2`` of one push.  Directions are
chosen greedily among :data:`CANDIDATES` to maximise ``log det`` of the summed
information: the one whose largest standard deviation, in units of the identifiability
limit (:mod:`.reasons`: 10 % of each mu, 5 deg), is smallest (a minimax design; a small
ridge makes the first choices well posed).  The
suggested experiment (the observed press, then one command of the observed push length
per direction) is then checked with FE sensitivities: its Gauss-Newton standard
deviations at the current estimate (``len(fit) + 1`` FE rollouts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Command

from ..config.commands import commands_to_list
from ..config.observations import Observations, leading_press
from ..config.scenario import Scenario
from ..errors import InputError
from .fit import _jacobian, covariance, scales
from .forward import FePredictor, stacked
from .noise import NoiseModel
from .prefit import limit_force
from .reasons import ANGLE_SIGMA_LIMIT_DEG, REL_SIGMA_LIMIT, identifiability

CANDIDATES = np.arange(0.0, 360.0, 5.0)
"""Candidate push directions, deg from world x."""
RIDGE = 1e-9


def push_sensitivity(theta, direction_deg: float, normal_force: float) -> np.ndarray:
    """``dg/dtheta`` (2, 3) for a push along ``direction_deg`` (N per unit of mu, N per deg)."""
    a = math.radians(direction_deg)
    s = np.array([[math.cos(a), math.sin(a)]])
    G = np.empty((2, 3))
    for j, h in enumerate((1e-6, 1e-6, 1e-4)):
        e = np.zeros(3)
        e[j] = h
        G[:, j] = normal_force * (limit_force(theta + e, s) - limit_force(theta - e, s))[0] / (2 * h)
    return G


def greedy_directions(theta, n: int, normal_force: float, force_sigma: float = 1.0) -> list[float]:
    """``n`` directions (deg), each minimising the largest standard deviation in units of
    the identifiability limit given the ones before (see the module docstring)."""
    D = np.array([REL_SIGMA_LIMIT * theta[0], REL_SIGMA_LIMIT * theta[1], ANGLE_SIGMA_LIMIT_DEG])
    sens = {d: push_sensitivity(np.asarray(theta, float), d, normal_force) * D / force_sigma for d in CANDIDATES}
    scale = max(float(np.sum(G * G)) for G in sens.values())
    info = RIDGE * scale * np.eye(3)
    chosen = []

    def worst(d):
        return float(np.max(np.diag(np.linalg.inv(info + sens[d].T @ sens[d]))))

    for _ in range(n):
        best = min(CANDIDATES, key=worst)
        chosen.append(float(best))
        info = info + sens[best].T @ sens[best]
    return chosen


@dataclass(frozen=True)
class Suggestion:
    """Suggested pushes and the FE-predicted standard deviations of their identification."""

    directions_deg: tuple[float, ...]
    distance: float
    commands: tuple[Command, ...]
    names: tuple[str, ...]
    sigma: np.ndarray
    identifiable: tuple[bool, ...]
    fe_rollouts: int

    def to_dict(self) -> dict:
        return {"directions_deg": list(self.directions_deg), "distance": self.distance,
                "commands": commands_to_list(self.commands),
                "predicted_sigma": {k: (float(s) if math.isfinite(s) else None) for k, s in zip(self.names, self.sigma)},
                "predicted_identifiable": dict(zip(self.names, self.identifiable)), "fe_rollouts": self.fe_rollouts}


def suggest(scenario: Scenario, obs: Observations, noise: NoiseModel, n: int, fit=("mu_x", "mu_y", "angle_deg"),
            distance: float | None = None) -> Suggestion:
    """``n`` pushes for ``scenario`` (its friction the current estimate), see the module docstring.

    Raises
    ------
    InputError
        The observations have no press or no in-plane push (nothing to take the press
        and the push length from) and no ``distance`` is given.
    """
    press = leading_press(obs)
    if not press:
        raise InputError("--suggest needs observations that start with the press (dz-only rows)")
    if distance is None:
        lengths = [math.hypot(c.dx, c.dy) for c in obs.commands]
        distance = max(lengths)
        if distance <= 0:
            raise InputError("--suggest needs at least one in-plane push in the observations (its length)")
    theta = np.array([scenario.mu_x, scenario.mu_y, scenario.angle_deg])
    normal = float(obs.values["force_z"][-1]) if "force_z" in obs.values else 1.0
    directions = greedy_directions(theta, n, normal)
    commands = press + tuple(Command(distance * math.cos(math.radians(d)), distance * math.sin(math.radians(d)), 0.0,
                                     0.0) for d in directions)
    return _checked(scenario, obs, noise, fit, directions, distance, commands)


def _checked(scenario, obs, noise, fit, directions, distance, commands) -> Suggestion:
    """FE-predicted standard deviations of the suggested experiment at the current estimate."""
    names = tuple(fit)
    columns = obs.columns
    dummy = Observations(commands, {k: np.zeros(len(commands)) for k in columns})
    predict = FePredictor(scenario, dummy, names)
    theta = np.array([getattr(scenario, k) for k in names], float)
    y = predict(theta)
    planned = Observations(commands, {k: y[i * len(commands):(i + 1) * len(commands)] for i, k in enumerate(columns)})
    sigma = noise.sigma(planned, scenario.size)
    r0 = (y - stacked(planned)) / sigma
    J = _jacobian(predict, stacked(planned), sigma, names, theta, r0)
    cov, undetermined = covariance(J, scales(names, theta))
    sd = np.where(undetermined, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    flags, _ = identifiability(names, theta, sd, planned, noise.pose_noise)
    return Suggestion(tuple(directions), float(distance), commands, names, sd, flags, predict.count)
