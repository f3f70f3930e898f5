"""The planning NLP on the reduced model (:mod:`.reduced_model`), transcribed with
CasADi ``Opti`` and solved by ipopt.

Commands ``u_k = (dx, dy[, dtheta])`` within the step bounds minimise the
final-pose error plus a small effort cost.  The return mapping of each step is
transcribed with its complementarity (slip only on the limit surface), relaxed to
``sigma (1 - rho) <= COMPLEMENTARITY_EPS``.  The problem is built once and re-solved
with new ``modifier`` values (the FE-minus-model mismatch of the correction loop).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..config.plan import PlanSpec
from .reduced_model import PushParameters, push_law, simulate_reduced
from .springback import Springback
from .target import naive_commands

COMPLEMENTARITY_EPS = 1e-8
"""Relaxation of ``sigma_k (1 - rho_k) = 0`` (slip, in units of max_step, times the
distance of the force from the limit surface, relative)."""


@dataclass(frozen=True)
class NlpSolution:
    """One solve of the planning NLP.

    ``commands`` (K, 3) ``(dx, dy, dtheta)``; ``lower`` / ``upper`` (K + 1, 3) reduced-model
    poses (without the modifier); ``variables`` the raw iterate (warm start).
    """

    commands: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    objective: float
    iterations: int
    success: bool
    return_status: str
    wall_time: float
    variables: dict = field(repr=False)


class ReducedPlanner:
    """The planning NLP on the reduced model, built once; re-solved with new
    ``target`` / ``modifier`` parameter values (CasADi ``Opti`` + ipopt).

    Per step k: the unit direction ``a_k`` of the generalised drive force on the
    limit surface (orthotropy frame, scaled by the friction limits), its level
    ``rho_k`` in [0, 1] (1 = on the surface) and the slip length ``sigma_k >= 0`` (in
    units of ``max_step``).  Poses follow explicitly through the one
    :func:`~.reduced_model.push_law` (the lower face slips along the surface normal,
    the upper face leads it by the elastic lag), the law the return mapping
    :func:`~.reduced_model.simulate_reduced` evaluates numerically.

    ``initial_lag`` (3,) ``upper - lower`` at the start (m, m, rad): zero from the pressed
    block at rest; a re-plan starts from the loaded state the executed pushes left, whose
    drive force is already on (or near) the limit surface.
    """

    def __init__(self, params: PushParameters, spec: PlanSpec, springback: Springback | None = None,
                 initial_lag=(0.0, 0.0, 0.0)):
        import casadi as ca

        if spec.yaw_targeted and not params.rotation:
            raise ValueError("a yaw target needs a reduced model with torsional parameters")
        self.params, self.spec = params, spec
        # the pose the target is for: loaded, or at rest after the release (spring-back of the lag)
        self.springback = springback if spec.target_state == "rest" else None
        K, d = spec.steps, (3 if spec.yaw_targeted else 2)
        opti = ca.Opti()
        A = opti.variable(d, K)
        rho = opti.variable(1, K)
        sigma = opti.variable(1, K)
        target = opti.parameter(3)
        modifier = opti.parameter(3)
        law = push_law(params)
        lag0 = np.asarray(initial_lag, float) * np.array([1.0, 1.0, float(spec.yaw_targeted)])
        lower, upper, cmds = [ca.DM.zeros(3, 1)], [ca.DM(lag0)], []
        effort = 0
        for k in range(K):
            a = A[:, k]
            # without a yaw target the force has no torque and the slip no yaw
            p, u, _ = law(lower[-1], a if spec.yaw_targeted else ca.vertcat(a, 0), rho[k],
                          spec.max_step * sigma[k])
            du = u - upper[-1]
            lower.append(p)
            upper.append(u)
            cmds.append(du)
            # constraints in units of the bounds: ipopt's feasibility tolerance is absolute
            opti.subject_to(ca.sumsqr(a) == 1)
            opti.subject_to(ca.sumsqr(du[:2] / spec.max_step) <= 1)
            effort += ca.sumsqr(du[:2] / spec.max_step)
            if spec.yaw_targeted:
                opti.subject_to(opti.bounded(-1, du[2] / spec.max_dtheta, 1))
                effort += (du[2] / spec.max_dtheta) ** 2
        opti.subject_to(opti.bounded(0, rho, 1))
        opti.subject_to(sigma >= 0)
        opti.subject_to(sigma * (1 - rho) <= COMPLEMENTARITY_EPS)
        final = lower[-1] + modifier
        if self.springback is not None:
            final = final + ca.DM(self.springback.fractions) * (upper[-1] - lower[-1])
        miss = final[:2] - target[:2]
        objective = ca.sumsqr(miss) / spec.tolerance**2 + spec.effort_weight * effort / K
        if spec.yaw_targeted:
            objective += (final[2] - target[2]) ** 2 / spec.yaw_tolerance**2
        opti.minimize(objective)
        # the starting point is complementary, with rho = 1 on its bound where sigma > 0:
        # ipopt's default bound push (1e-2) would move it off the complementarity set
        opti.solver("ipopt", {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes",
                              "ipopt.max_iter": 3000, "ipopt.tol": 1e-10,
                              "ipopt.mu_strategy": "adaptive", "ipopt.bound_push": 1e-8,
                              "ipopt.bound_frac": 1e-8})
        self._ca, self.opti = ca, opti
        self._A, self._rho, self._sigma = A, rho, sigma
        self._target, self._modifier = target, modifier
        self._lower, self._upper = ca.horzcat(*lower), ca.horzcat(*upper)
        self._cmds = ca.horzcat(*cmds)
        self._objective = objective

    def predicted_final(self, solution: NlpSolution) -> np.ndarray:
        """The reduced model's final pose (3,) in the target's state (without the modifier)."""
        if self.springback is None:
            return solution.lower[-1]
        return self.springback.rest(solution.lower[-1], solution.upper[-1])

    def initial_guess(self) -> dict:
        """The variables of the naive commands (clipped to the step bounds), from the
        reduced model's return mapping: a feasible, complementary starting point."""
        p, spec = self.params, self.spec
        cmds = naive_commands(spec)
        cmds[:, :2] *= min(1.0, spec.max_step / max(float(np.hypot(*cmds[0, :2])), 1e-300))
        cmds[:, 2] = np.clip(cmds[:, 2], -spec.max_dtheta, spec.max_dtheta)
        traj = simulate_reduced(p, cmds)
        m = np.array([p.mu_x, p.mu_y])
        f_local = traj.force[1:, :2] @ p.frame  # rows R^T f
        scaled = f_local / (p.normal_force * m)
        if spec.yaw_targeted:
            scaled = np.column_stack([scaled, traj.force[1:, 2] / p.max_torque])
        rho = np.linalg.norm(scaled, axis=1)
        A = np.where(rho[:, None] > 0, scaled / np.where(rho > 0, rho, 1.0)[:, None], 0.0)
        A[rho == 0, 0] = 1.0
        slip = np.diff(traj.lower[:, :2], axis=0) @ p.frame
        per_unit = spec.max_step * math.sqrt(p.mu_x * p.mu_y) * np.linalg.norm(A[:, :2] / m, axis=1)
        sigma = np.where(traj.sliding[1:], np.linalg.norm(slip, axis=1) / np.maximum(per_unit, 1e-300), 0.0)
        return {"A": A.T, "rho": np.minimum(rho, 1.0)[None, :], "sigma": sigma[None, :]}

    def solve(self, modifier=(0.0, 0.0, 0.0), warm: NlpSolution | None = None) -> NlpSolution:
        """Solve for the commands; ``modifier`` (3,) is added to the predicted final pose.

        A failed ipopt run returns its last iterate with ``success = False``.
        """
        opti = self.opti
        opti.set_value(self._target, list(self.spec.target))
        opti.set_value(self._modifier, [float(v) for v in modifier])
        guess = warm.variables if warm is not None else self.initial_guess()
        opti.set_initial(self._A, guess["A"])
        opti.set_initial(self._rho, guess["rho"])
        opti.set_initial(self._sigma, guess["sigma"])
        t0 = time.perf_counter()
        try:
            sol = opti.solve()
        except RuntimeError:
            sol = opti.debug
        wall = time.perf_counter() - t0
        stats = opti.stats()
        value = sol.value

        def mat(x):
            return np.atleast_2d(np.asarray(value(x), float))

        A = mat(self._A).reshape(self._A.shape)
        return NlpSolution(
            commands=mat(self._cmds).reshape(3, -1).T.copy(),
            lower=mat(self._lower).reshape(3, -1).T.copy(),
            upper=mat(self._upper).reshape(3, -1).T.copy(),
            objective=float(value(self._objective)),
            iterations=int(stats.get("iter_count", -1)),
            success=bool(stats.get("success", False)),
            return_status=str(stats.get("return_status", "")),
            wall_time=wall,
            variables={"A": A, "rho": mat(self._rho).reshape(1, -1), "sigma": mat(self._sigma).reshape(1, -1)},
        )


def model_consistency(params: PushParameters, solution: NlpSolution) -> float:
    """Largest difference (m or rad) between the NLP's lower-face poses and the return
    mapping of its commands (:func:`simulate_reduced`): both go through the one
    :func:`push_law`, so this measures the relaxation of the NLP's complementarity
    ``sigma (1 - rho) <= COMPLEMENTARITY_EPS`` (slip off the limit surface)."""
    cmds = solution.commands.copy()
    if not params.rotation:
        cmds[:, 2] = 0.0
    traj = simulate_reduced(params, cmds)
    return float(np.abs(traj.lower - solution.lower).max())

