"""Plans that hold under the identified uncertainty (issue 42): the nominal plan
refined so that its final pose is within tolerance with a stated probability over the
identified parameter distribution, and a Monte Carlo of FE rollouts that checks it.

Method (docs/planning.md, "Robust plans"):

1. The nominal plan (:func:`~.planner.plan`) for the estimate ``theta_hat``.
2. The ``S = 2 n + 1`` sigma points ``theta_i`` of the distribution
   (:mod:`.distribution`), each an FE model on the verification mesh, pressed once.
   At commands ``u`` (m, 3) each gives the final pose ``p_i(u)`` (loaded or at rest) and
   its command Jacobian ``J_i = dp_i/du``: exact for a loaded target with a bonded pad
   (:func:`fe_contact.rollout_derivatives`), else (no release or pad derivatives yet)
   the rigid-follow approximation ``dp/du_k = I`` (the final pose moves with the total
   command) at the nominal commands, then Broyden's rank-one update from each
   evaluation to the next (:func:`broyden`).
3. The robust objective is the expected weighted squared miss plus the NLP's effort

       Phi(u) = sum_i w_i |W^(1/2) (p_i(u) - x*)|^2 + u^T E u
              = |W^(1/2)(m - x*)|^2 + tr(W S_p) + u^T E u,

   ``W``, ``E`` of :mod:`.refine`, ``m``, ``S_p`` the sigma points' mean and covariance of
   the final pose: the miss of the mean and the spread, together.  Levenberg-Marquardt
   steps minimise it, each the least-squares solution of the stacked, linearised system
   ``sqrt(w_i) W^(1/2) (r_i + J_i d)``, ``E^(1/2)(u + d)``, ``sqrt(lambda) d / b``, the
   commands projected onto the step bounds; a step that does not lower ``Phi`` is
   refused and ``lambda`` raised.
4. The predicted probability of success is ``P(p in tolerance)`` for
   ``p ~ N(m, S_p)`` (:func:`~.distribution.success_probability`).  The refinement
   stops at the first commands reaching ``level`` (so a zero covariance, where the
   nominal plan's probability is 1, returns the nominal commands unchanged), or after
   ``max_iterations`` evaluations with the commands of the highest probability found.
5. Check: ``monte_carlo`` truths drawn from the distribution (seeded), each an FE model
   on the verification mesh rolling out the robust and the nominal commands; the
   fraction within tolerance and its Clopper-Pearson 95 % interval.

Cost: ``S`` FE rollouts (with derivatives where exact) per evaluation, at most
``max_iterations`` evaluations, ``S`` presses; the check ``monte_carlo`` presses and
``2 monte_carlo`` rollouts.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from fe_contact import wrap_angle

from ..config.plan import PlanSpec, press_commands
from ..config.scenario import Scenario
from .distribution import Distribution, binomial_interval, pose_moments, success_probability
from .reduced_model import PushParameters, steady_lag
from .result import PlanResult
from .rollouts import FeRollouts, Rollout
from .target import pose_error, within_tolerance

SLIDE_STEPS = None
"""Commands of :func:`slide_start`'s final slide at most (None: as many as the other commands'
bounds allow, up to K - 1).  A lag built along a badly known axis relaxes slowly while the
block slides along the well-known one (the flow rule turns the slip only by ``(mu_y / mu_x)^2``
of the force's turn), so the longest slide the bounds allow is the start: on rotated axes
(30 degrees, mu_x = 0.4 +- 0.015, mu_y = 0.15 +- 0.003, 10 steps) a cap of 2 left the
refinement at 0.66 after 12 evaluations, the longest slide reached 0.91 (benchmarks/robust_rotated.py)."""
DIRECTIONS = 72
"""Slip directions (every 5 degrees) :func:`quiet_direction` compares."""
LAMBDA0 = 1e-2
"""The first Levenberg-Marquardt damping, relative to the diagonal of the Gauss-Newton matrix
(Marquardt's scaling): the linearisation holds over a fraction of a step only where a
contact switches between stick and slip."""
LAMBDA_GROWTH = 4.0
"""Damping times this after a refused step."""
LAMBDA_SHRINK = 2.0
"""Damping over this after an accepted one."""


@dataclass(frozen=True)
class Evaluation:
    """The sigma points' FE rollouts of one set of commands."""

    commands: np.ndarray  # (m, 3)
    finals: np.ndarray  # (S, 3) final poses, m and rad
    jacobians: np.ndarray  # (S, 3, m, 3)
    mean: np.ndarray  # (3,)
    covariance: np.ndarray  # (3, 3)
    probability: float
    objective: float
    at_estimate: Rollout  # the rollout of sigma point 0 (theta_hat)
    wall_time: float

    def to_dict(self) -> dict:
        sd = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return {"predicted_probability": self.probability, "objective": self.objective,
                "mean_final": [float(self.mean[0]), float(self.mean[1]), math.degrees(float(self.mean[2]))],
                "sd_final": [float(sd[0]), float(sd[1]), math.degrees(float(sd[2]))],
                "wall_time_s": self.wall_time}


@dataclass(frozen=True)
class MonteCarlo:
    """The check of one plan: final poses (N, 3) of the truths and how many are within tolerance."""

    finals: np.ndarray
    within: int

    @property
    def count(self) -> int:
        return len(self.finals)

    def to_dict(self, spec: PlanSpec) -> dict:
        lo, hi = binomial_interval(self.within, self.count)
        return {"count": self.count, "within_tolerance": self.within,
                "fraction": self.within / self.count if self.count else None,
                "interval_95": [lo, hi], "interval_method": "Clopper-Pearson (exact binomial)",
                "position_errors": [pose_error(p, spec)[0] for p in self.finals]}


@dataclass(frozen=True)
class RobustResult:
    """A robust plan: ``result`` the plan.json content's plan (the robust commands, verified
    at the estimate), ``nominal`` the nominal plan it started from."""

    result: PlanResult
    nominal: PlanResult
    distribution: Distribution
    reached: bool
    evaluations: tuple[Evaluation, ...]
    best: int  # index of the reported evaluation
    monte_carlo: dict  # "robust" / "nominal" -> MonteCarlo (empty without a check)
    truths: np.ndarray
    redrawn: int
    rollouts: dict  # sigma-point and Monte Carlo FE rollouts and presses
    wall_time: dict


class SigmaRollouts:
    """One pressed FE model on the verification mesh per sigma point (``after``: the pushes
    executed after the press, applied once to each; poses are then relative to where they
    leave it, as :class:`~.rollouts.FeRollouts` has them)."""

    def __init__(self, scenario: Scenario, distribution: Distribution, spec: PlanSpec, after=()):
        self.spec = spec
        self.points, self.weights = distribution.sigma_points()
        press = press_commands(scenario)
        self.fe = [FeRollouts(distribution.scenario(scenario, theta).model(), press, f"sigma point {i}",
                              release=scenario.release, after=tuple(after)) for i, theta in enumerate(self.points)]
        # exact command Jacobians of the loaded final pose with a bonded pad
        self.exact = spec.target_state == "loaded" and scenario.pad is None

    def evaluate(self, commands: np.ndarray) -> Evaluation:
        t0 = time.perf_counter()
        spec, m = self.spec, len(commands)
        finals, jacs, first = [], [], None
        for fe in self.fe:
            if self.exact:
                roll, J = fe.rollout_with_jacobian(commands)
            else:  # rigid follow: d final / d u_k = I
                roll, J = fe.rollout(commands), np.repeat(np.eye(3)[:, None, :], m, axis=1)
            first = roll if first is None else first
            finals.append(roll.final(spec.target_state))
            jacs.append(J)
        finals = np.array(finals)
        mean, cov = pose_moments(finals, self.weights)
        return Evaluation(np.array(commands, float), finals, np.array(jacs), mean, cov,
                          success_probability(mean, cov, spec), objective(finals, self.weights, commands, spec),
                          first, time.perf_counter() - t0)

    @property
    def count(self) -> int:
        return sum(fe.count for fe in self.fe)


def _weights(spec: PlanSpec, m: int) -> tuple[list, np.ndarray, np.ndarray]:
    """Active components, ``W^(1/2)`` (per component) and ``E^(1/2)`` (per (k, c), step-major)."""
    cols = [0, 1, 2] if spec.yaw_targeted else [0, 1]
    w = np.sqrt(np.array([spec.tolerance**-2, spec.tolerance**-2, spec.yaw_tolerance**-2]))[cols]
    bounds = np.array([spec.max_step, spec.max_step, spec.max_dtheta])[cols]
    return cols, w, np.sqrt(spec.effort_weight / m) / np.tile(bounds, m)


def _misses(finals: np.ndarray, spec: PlanSpec) -> np.ndarray:
    """Final poses (S, 3) minus the target, yaw wrapped."""
    r = finals - np.asarray(spec.target, float)
    r[:, 2] = wrap_angle(r[:, 2])
    return r


def objective(finals, weights, commands, spec: PlanSpec) -> float:
    """``Phi`` of the module docstring."""
    cols, w, e = _weights(spec, len(commands))
    r = _misses(np.asarray(finals), spec)[:, cols] * w
    return float(weights @ np.sum(r**2, axis=1) + np.sum((e * np.asarray(commands)[:, cols].ravel()) ** 2))


def lm_step(ev: Evaluation, weights: np.ndarray, spec: PlanSpec, lam: float) -> np.ndarray:
    """The damped Gauss-Newton commands (m, 3) from ``ev``, projected onto the step bounds."""
    u, m = ev.commands, len(ev.commands)
    cols, w, e = _weights(spec, m)
    r = _misses(ev.finals, spec)[:, cols]
    rows = [np.sqrt(wi) * w[:, None] * J[cols][:, :, cols].reshape(len(cols), -1)
            for wi, J in zip(weights, ev.jacobians, strict=True)]
    b = [-np.sqrt(wi) * w * ri for wi, ri in zip(weights, r, strict=True)]
    x = u[:, cols].ravel()
    A = np.vstack([*rows, np.diag(e)])
    scale = np.sqrt(np.maximum(np.sum(A**2, axis=0), 1e-300))  # Marquardt: sqrt(diag(A^T A))
    A = np.vstack([A, np.diag(np.sqrt(lam) * scale)])
    rhs = np.concatenate([*b, -e * x, np.zeros(x.size)])
    d = np.linalg.lstsq(A, rhs, rcond=None)[0]
    out = u.copy()
    out[:, cols] = (x + d).reshape(m, len(cols))
    length = np.hypot(out[:, 0], out[:, 1])
    out[:, :2] *= np.minimum(1.0, spec.max_step / np.maximum(length, 1e-300))[:, None]
    out[:, 2] = np.clip(out[:, 2], -spec.max_dtheta, spec.max_dtheta) if spec.yaw_targeted else 0.0
    return out


def broyden(previous: Evaluation, ev: Evaluation) -> Evaluation:
    """``ev`` with each sigma point's Jacobian Broyden-updated from ``previous``'s:
    ``J += (dp - J du) du^T / |du|^2`` (du the change of the commands, flattened;
    ``dp`` of the final pose), so that ``J du = dp`` (Broyden 1965, the "good" update)."""
    du = (ev.commands - previous.commands).ravel()
    nn = float(du @ du)
    if nn == 0.0:
        return dataclasses.replace(ev, jacobians=previous.jacobians)
    S, m = len(ev.finals), len(ev.commands)
    J = previous.jacobians.reshape(S, 3, 3 * m)
    dp = ev.finals - previous.finals
    dp[:, 2] = wrap_angle(dp[:, 2])
    J = J + np.einsum("si,j->sij", dp - J @ du, du) / nn
    return dataclasses.replace(ev, jacobians=J.reshape(S, 3, m, 3))


def quiet_direction(params: PushParameters, distribution: Distribution, toward) -> np.ndarray:
    """The unit slip direction (2,) whose steady-sliding lag (:func:`~.reduced_model.steady_lag`)
    varies least over the sigma points, among :data:`DIRECTIONS` directions within 90 degrees of ``toward``."""
    points, weights = distribution.sigma_points()
    models = [dataclasses.replace(params, **{("angle" if k == "angle_deg" else k): (math.radians(v) if k == "angle_deg"
                                                                                     else float(v))
                                             for k, v in zip(distribution.names, theta, strict=True) if k != "young"})
              for theta in points]
    best, spread_min = None, math.inf
    for phi in 2 * math.pi * np.arange(DIRECTIONS) / DIRECTIONS:
        d = np.array([math.cos(phi), math.sin(phi)])
        if d @ toward < 0:
            continue
        lags = np.array([steady_lag(m, d) for m in models])
        spread = float(weights @ np.sum((lags - weights @ lags) ** 2, axis=1))
        if spread < spread_min:
            best, spread_min = d, spread
    return best


def slide_start(nominal: PlanResult, distribution: Distribution, spec: PlanSpec) -> np.ndarray | None:
    """A second start of the refinement (step 3): commands whose last ones (as many as leave the
    others within the bounds, at most :data:`SLIDE_STEPS`) slide ``max_step`` each along
    :func:`quiet_direction`, the others straight and equal towards the target plus the lag that
    slide leaves (less its spring-back for a rest target), within the step bounds; None with a
    yaw target or a single step."""
    K = spec.steps
    target = np.asarray(spec.target[:2], float)
    if spec.yaw_targeted or K < 2 or not np.any(target):
        return None
    d = quiet_direction(nominal.params, distribution, target)
    lag = steady_lag(nominal.params, d)
    if spec.target_state == "rest":
        lag = (1.0 - nominal.springback.position) * lag
    last = spec.max_step * d
    for n in range(K - 1 if SLIDE_STEPS is None else min(SLIDE_STEPS, K - 1), 0, -1):  # the longest that fits
        step = (target + lag - n * last) / (K - n)
        if np.hypot(*step) <= spec.max_step:
            break
    step *= min(1.0, spec.max_step / max(float(np.hypot(*step)), 1e-300))
    out = np.zeros((K, 3))
    out[:K - n, :2], out[K - n:, :2] = step, last
    return out


def spread(ev: Evaluation, spec: PlanSpec) -> float:
    """``tr(W S_p)``: the part of ``Phi`` the final poses' spread makes, whatever their mean."""
    cols, w, _ = _weights(spec, len(ev.commands))
    return float(np.sum(w**2 * np.diag(ev.covariance)[cols]))


def refine(sigma: SigmaRollouts, commands: np.ndarray, spec: PlanSpec, log=None,
           alternative: np.ndarray | None = None) -> list[Evaluation]:
    """Step 3-4 of the module docstring from ``commands``: every evaluation, in order.
    ``alternative``: commands evaluated second, where the first do not reach the level; the
    steps start from the one of the smaller spread (:func:`spread`)."""
    level, evals = spec.robust.level, []
    current, lam = None, LAMBDA0
    for it in range(spec.robust.max_iterations):
        if it == 1 and alternative is not None:
            commands = alternative
        ev = sigma.evaluate(commands)
        if not sigma.exact and current is not None:
            ev = broyden(evals[-1], ev)
        evals.append(ev)
        accepted = current is None or ev.objective < current.objective
        if it == 1 and alternative is not None:  # the start of the smaller spread: the steps centre it
            accepted = spread(ev, spec) < spread(current, spec)
        if log is not None:
            log(f"      robust evaluation {it + 1}{' (second start)' if it == 1 and alternative is not None else ''}: "
                f"predicted probability {ev.probability:.4f}, objective {ev.objective:.5g}"
                f"{'' if accepted else ' (step refused)'}")
        if accepted:
            current, lam = ev, lam / (LAMBDA_SHRINK if current is not None else 1.0)
            if ev.probability >= level:
                break
        elif not (it == 1 and alternative is not None):  # a worse second start is no refused step
            lam *= LAMBDA_GROWTH
            if not sigma.exact:  # the secant information of the refused step too
                current = dataclasses.replace(current, jacobians=ev.jacobians)
        commands = lm_step(current, sigma.weights, spec, lam)
    return evals


def monte_carlo(scenario: Scenario, distribution: Distribution, spec: PlanSpec, plans: dict,
                truths: np.ndarray, after=()) -> tuple[dict, int]:
    """Step 5: ``{name: MonteCarlo}`` of the commands ``plans[name]`` over ``truths`` (each
    from the state ``after`` leaves), and the FE rollouts run."""
    press, finals, n = press_commands(scenario), {k: [] for k in plans}, 0
    for i, theta in enumerate(truths):
        fe = FeRollouts(distribution.scenario(scenario, theta).model(), press, f"truth {i}",
                        release=scenario.release, after=tuple(after))
        for name, u in plans.items():
            finals[name].append(fe.rollout(u).final(spec.target_state))
        n += fe.count
    return {k: MonteCarlo(np.array(v).reshape(-1, 3), sum(within_tolerance(p, spec) for p in v))
            for k, v in finals.items()}, n


def plan_robust(scenario: Scenario, distribution: Distribution, spec: PlanSpec, nominal: PlanResult,
                log=None, after=()) -> RobustResult:
    """The robust plan of the module docstring from the ``nominal`` plan of ``scenario``
    (whose parameters are the distribution's mean) and its Monte Carlo check.  ``after``:
    the pushes executed after the press (a re-plan, :mod:`.replan`; ``spec`` and
    ``nominal`` relative to the pose they leave); the sigma points and the truths start
    from the state they leave in each.

    Raises
    ------
    PlanningError
        An FE rollout failed.
    ValueError
        The distribution's draws are mostly unphysical (:meth:`Distribution.sample`).
    """
    t0 = time.perf_counter()
    sigma = SigmaRollouts(scenario, distribution, spec, after)
    evals = refine(sigma, nominal.commands, spec, log, alternative=slide_start(nominal, distribution, spec))
    t1 = time.perf_counter()
    best = max(range(len(evals)), key=lambda i: (evals[i].probability, -evals[i].objective))
    ev, level = evals[best], spec.robust.level
    reached = ev.probability >= level
    truths, redrawn = distribution.sample(spec.robust.monte_carlo, np.random.default_rng(spec.robust.seed))
    checks, mc_rollouts = monte_carlo(scenario, distribution, spec, {"robust": ev.commands,
                                                                     "nominal": nominal.commands}, truths, after)
    message = (f"predicted probability {ev.probability:.4g} of the final pose within tolerance over the "
               f"identified distribution ({len(sigma.fe)} sigma points) "
               + (f">= level {level:g}" if reached else
                  f"< level {level:g}: no commands found reach it in {len(evals)} evaluations; the commands of the "
                  "highest probability found are reported"))
    status = "converged" if reached else "not_converged"
    if nominal.status == "infeasible":  # its reach from the start (a rest target's from its spring-back)
        status = "infeasible"
    result = dataclasses.replace(nominal, verified=ev.at_estimate, status=status, message="robust plan: " + message)
    if log is not None:
        log(f"robust plan: {message}")
    return RobustResult(
        result=result, nominal=nominal, distribution=distribution, reached=reached, evaluations=tuple(evals),
        best=best, monte_carlo=checks, truths=truths, redrawn=redrawn,
        rollouts={"sigma_points": len(sigma.fe), "sigma_point_rollouts": sigma.count,
                  "monte_carlo_rollouts": mc_rollouts, "monte_carlo_truths": len(truths),
                  "presses": len(sigma.fe) + len(truths)},
        wall_time={"refinement": t1 - t0, "monte_carlo": time.perf_counter() - t1})


def robust_document(robust: RobustResult, spec: PlanSpec) -> dict:
    """``plan.json``'s ``robust`` entry (poses ``[x (m), y (m), yaw (deg)]``)."""
    from .document import _commands_json

    ev = robust.evaluations[robust.best]
    nominal_ev = robust.evaluations[0]
    return {
        "method": "sigma points (unscented, 2n+1) on the verification mesh; Levenberg-Marquardt on the expected "
                  "weighted squared miss; Gaussian final pose; docs/planning.md",
        "level": spec.robust.level, "reached": robust.reached,
        "predicted_probability": ev.probability,
        "nominal_predicted_probability": nominal_ev.probability,
        "exact_jacobians": spec.target_state == "loaded" and robust.result.scenario.pad is None,
        "distribution": robust.distribution.to_dict(),
        "evaluations": [e.to_dict() for e in robust.evaluations], "reported_evaluation": robust.best + 1,
        "nominal": {"status": robust.nominal.status, "message": robust.nominal.message,
                    "commands": _commands_json(robust.nominal.commands)},
        "monte_carlo": {"truths": len(robust.truths), "seed": spec.robust.seed, "redrawn": robust.redrawn,
                        "mesh": "verification",
                        **{k: v.to_dict(spec) for k, v in robust.monte_carlo.items()}},
        "fe_rollouts": robust.rollouts, "wall_time_s": robust.wall_time,
    }
