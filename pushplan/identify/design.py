"""Experiment design: N push directions that make ``(mu_x, mu_y, angle)`` identifiable.

Sensitivities come from the reduced model of :mod:`pushplan.planning.reduced_model`
(the block as one elastic-plastic spring on the elliptic limit surface), its
compliance and normal force calibrated from the observations (least squares of the
lag ``upper - lower`` against the drive force, ``force_z``): the whole sequence of
pushes from the pressed block is simulated, transients included (the first push of a
new direction mostly loads the spring).  Central differences give the Jacobian of the
observed columns (forces, lower-face positions) over their noise; directions are
chosen greedily among :data:`CANDIDATES`, each the one after which the largest standard
deviation, in units of the identifiability limit (:mod:`.reasons`: 10 % of each mu,
5 deg), is smallest (a minimax design; a small ridge makes the first choices well
posed).  Without pose and force columns to calibrate on, the steady-sliding force
``g(s) = N R M^2 R^T s / ||M R^T s||`` (:func:`~.prefit.limit_force`) stands in.  The
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
from ..planning.reduced_model import PushParameters, simulate_reduced
from .fit import _jacobian, covariance, scales
from .forward import FePredictor, stacked
from .noise import NoiseModel
from .prefit import PREFIT_COLUMNS, limit_force
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


def _limits(theta) -> np.ndarray:
    return np.array([REL_SIGMA_LIMIT * theta[0], REL_SIGMA_LIMIT * theta[1], ANGLE_SIGMA_LIMIT_DEG])


def steady_information(theta, directions, normal_force: float, noise: NoiseModel) -> np.ndarray:
    """Information of steadily sliding pushes (3 x 3, parameters in units of their limits)."""
    info = np.zeros((3, 3))
    for d in directions:
        g = normal_force * np.linalg.norm(limit_force(theta, np.array([[math.cos(math.radians(d)),
                                                                       math.sin(math.radians(d))]])))
        G = push_sensitivity(theta, d, normal_force) * _limits(theta) / math.hypot(noise.force_noise,
                                                                                    noise.force_noise_rel * g)
        info += G.T @ G
    return info


def calibrated_spring(obs: Observations):
    """``(compliance m/N, normal force N)`` from the observations, or None without the columns."""
    if any(k not in obs.values for k in PREFIT_COLUMNS):
        return None
    upper = np.cumsum([[c.dx, c.dy] for c in obs.commands], axis=0)
    lag = upper - np.stack([obs.values["lower_x"], obs.values["lower_y"]], axis=1)
    g = np.stack([obs.values["force_x"], obs.values["force_y"]], axis=1)  # the drive force on the block
    gg = float((g * g).sum())
    normal = float(np.max(-obs.values["force_z"]))  # the pressed rows' (a last row after a release has none)
    compliance = float((lag * g).sum()) / gg if gg > 0 else 0.0
    if compliance <= 0 or normal <= 0:
        return None  # not a spring: the steady-sliding information stands in
    return compliance, normal


def sequence_information(theta, directions, distance: float, spring, noise: NoiseModel) -> np.ndarray:
    """Information of the push sequence on the reduced model (3 x 3, parameters in units
    of their limits): forces and lower-face positions after every push."""
    u = np.array([[distance * math.cos(math.radians(d)), distance * math.sin(math.radians(d)), 0.0]
                  for d in directions])
    compliance, normal = spring

    def observed(t):
        p = PushParameters(t[0], t[1], math.radians(t[2]), normal, compliance)
        tr = simulate_reduced(p, u)
        return tr.force[1:, :2].ravel(), tr.lower[1:, :2].ravel()

    f0, _ = observed(theta)
    sig = np.concatenate([np.hypot(noise.force_noise, noise.force_noise_rel * np.abs(f0)),
                          np.full(f0.size, noise.pose_noise)])
    J = np.empty((sig.size, 3))
    for j, h in enumerate((1e-5, 1e-5, 1e-3)):
        e = np.zeros(3)
        e[j] = h
        J[:, j] = (np.concatenate(observed(theta + e)) - np.concatenate(observed(theta - e))) / (2 * h)
    J = J / sig[:, None] * _limits(theta)
    return J.T @ J


def greedy_directions(theta, n: int, information) -> list[float] | None:
    """``n`` directions (deg), each minimising the largest standard deviation in units of
    the identifiability limit given the ones before; ``information(directions)`` is 3 x 3.
    None when no single direction carries information (zero or non-finite)."""
    scale = max(float(np.trace(information([d]))) for d in CANDIDATES[::6])
    if not (math.isfinite(scale) and scale > 0):
        return None  # the model predicts no information at all (no push slides): the caller's fallback
    ridge = RIDGE * scale * np.eye(3)
    chosen: list[float] = []

    def worst(d):
        info = ridge + information(chosen + [float(d)])
        if not np.all(np.isfinite(info)):
            return math.inf
        try:
            return float(np.max(np.diag(np.linalg.inv(info))))
        except np.linalg.LinAlgError:  # singular to rounding: this direction adds nothing usable
            return math.inf

    for _ in range(n):
        chosen.append(float(min(CANDIDATES, key=worst)))
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
                "predicted_sigma": {k: (float(s) if math.isfinite(s) else None) for k, s in zip(self.names, self.sigma, strict=True)},
                "predicted_identifiable": dict(zip(self.names, self.identifiable, strict=True)), "fe_rollouts": self.fe_rollouts}


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
    spring = calibrated_spring(obs)
    directions = None
    if spring is not None:  # None too when the calibrated spring never slides over these pushes
        directions = greedy_directions(theta, n, lambda ds: sequence_information(theta, ds, distance, spring, noise))
    if directions is None:
        normal = max(float(np.max(-obs.values["force_z"])), 1e-300) if "force_z" in obs.values else 1.0
        directions = greedy_directions(theta, n, lambda ds: steady_information(theta, ds, normal, noise))
    if directions is None:
        raise InputError(f"--suggest: the friction estimate ({theta[0]:g}, {theta[1]:g}, {theta[2]:g} deg) gives "
                         "no push any information on the friction")
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
