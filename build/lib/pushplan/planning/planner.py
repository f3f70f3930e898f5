"""``pushplan plan``: upper-face commands that bring the block's lower face to a target
pose, planned on a reduced model in CasADi and corrected with FE rollouts.

Strategy (the README explains why):

1. Calibrate :mod:`pushplan.reduced_model` from FE rollouts on the coarse planning
   mesh: the naive push (also the baseline) gives the shear compliance and the
   normal force; for a yaw target, a pure rotation gives the torsional compliance
   and the torque of torsional sliding.
2. Solve the planning NLP on the reduced model (CasADi ``Opti`` + ipopt):
   commands ``u_k = (dx, dy[, dtheta])`` within the step bounds minimising the
   final-pose error plus a small effort cost.  The return mapping of each step is
   transcribed with its complementarity (slip only on the limit surface), relaxed
   to ``sigma (1 - rho) <= COMPLEMENTARITY_EPS``.
3. Modifier adaptation: roll the plan out in the FE model, add the FE-minus-model
   final-pose mismatch to the NLP's prediction and re-solve, until the FE pose is
   within tolerance.  First on the planning mesh, then on the verification mesh
   (the scenario's ``[block]`` mesh), whose rollout is the reported result.

The scenario's ``[[load]]`` entries are the press (``dz`` only), applied before
the planned commands; the ``[plan]`` table reads (SI units)::

    [plan]
    x = 0.9e-3                 # target lower-face centroid displacement, m
    y = 0.9e-3
    yaw_deg = 5.0              # optional target lower-face yaw (enables dtheta commands)
    steps = 4                  # K planned commands
    max_step = 0.4e-3          # bound on each command's in-plane length, m
    max_dtheta_deg = 2.0       # bound on each command's rotation (only with yaw_deg)
    tolerance = 3e-6           # final position tolerance, m (default 0.25 % of travel)
    yaw_tolerance_deg = 0.1    # final yaw tolerance (default 0.1)
    effort_weight = 1e-3       # weight of sum |u_k / bound|^2 against (error / tolerance)^2
    planning_elements = [6, 6, 2]
    planning_quadrature = 2
    max_rollouts = 6           # FE rollouts per mesh in the correction loop

The poses are those under load (upper face still held after the last command);
release is not modelled.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from fe_contact import Command, Model, State, StepReport, initial_state, step

from ..config.commands import commands_to_list as commands_to_json
from .reduced_model import PushParameters, calibrate, simulate_reduced
from ..config.scenario import Scenario, ScenarioError
from ..config.validate import integer as _integer, number as _number, triple as _triple
from ..errors import SolverFailure

PLAN_KEYS = frozenset({
    "x", "y", "yaw_deg", "steps", "max_step", "max_dtheta_deg", "tolerance", "yaw_tolerance_deg",
    "effort_weight", "planning_elements", "planning_quadrature", "max_rollouts",
})
DEFAULT_TOLERANCE_REL = 0.0025
"""Default position tolerance as a fraction of the travel distance."""
DEFAULT_YAW_TOLERANCE_DEG = 0.1
DEFAULT_EFFORT_WEIGHT = 1e-3
DEFAULT_PLANNING_ELEMENTS = (6, 6, 2)
DEFAULT_PLANNING_QUADRATURE = 2
DEFAULT_MAX_ROLLOUTS = 6
COMPLEMENTARITY_EPS = 1e-8
"""Relaxation of ``sigma_k (1 - rho_k) = 0`` (slip, in units of max_step, times the
distance of the force from the limit surface, relative)."""
NO_PROGRESS = 0.1
"""An infeasible plan stops when the error changes by less than this fraction of the tolerance."""


class PlanningError(SolverFailure):
    """An FE rollout failed (the step report's status and message are quoted)."""


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


# -- problem -----------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanSpec:
    """A validated ``[plan]`` table (SI units, radians).

    ``target`` is the lower-face pose ``(x, y, yaw)`` relative to the rest pose;
    ``yaw`` is 0 and ignored when ``yaw_targeted`` is false.
    """

    target: tuple[float, float, float]
    yaw_targeted: bool
    steps: int
    max_step: float
    max_dtheta: float
    tolerance: float
    yaw_tolerance: float
    effort_weight: float
    planning_elements: tuple[int, int, int]
    planning_quadrature: int
    max_rollouts: int

    @property
    def travel(self) -> float:
        """Distance from the rest pose to the target position, m."""
        return math.hypot(self.target[0], self.target[1])

    @property
    def reachable(self) -> bool:
        """Whether the target is within K times the step bounds."""
        ok = self.travel <= self.steps * self.max_step
        if self.yaw_targeted:
            ok = ok and abs(self.target[2]) <= self.steps * self.max_dtheta
        return ok

    def to_dict(self) -> dict:
        return {
            "x": self.target[0], "y": self.target[1],
            "yaw_deg": math.degrees(self.target[2]) if self.yaw_targeted else None,
            "steps": self.steps, "max_step": self.max_step,
            "max_dtheta_deg": math.degrees(self.max_dtheta) if self.yaw_targeted else None,
            "tolerance": self.tolerance, "yaw_tolerance_deg": math.degrees(self.yaw_tolerance),
            "effort_weight": self.effort_weight, "planning_elements": list(self.planning_elements),
            "planning_quadrature": self.planning_quadrature, "max_rollouts": self.max_rollouts,
            "travel": self.travel,
        }


def parse_plan(scenario: Scenario) -> PlanSpec:
    """Validate the scenario's ``[plan]`` table and its press.

    Raises
    ------
    ScenarioError
        Missing table, unknown key or bad value (named), or a ``[[load]]`` that is not
        a press (``dz`` only, net compression).
    """
    table = scenario.extra.get("plan")
    if table is None:
        raise ScenarioError(f"scenario {scenario.name!r} has no [plan] table")
    if not isinstance(table, dict):
        raise ScenarioError(f"plan must be a table, got {table!r}")
    for k in table:
        if k not in PLAN_KEYS:
            raise ScenarioError(f"unknown key plan.{k} (allowed: {', '.join(sorted(PLAN_KEYS))})")
    for k in ("x", "y", "steps", "max_step"):
        if k not in table:
            raise ScenarioError(f"missing key plan.{k}")
    press_commands(scenario)
    if scenario.mu_x <= 0 or scenario.mu_y <= 0:
        raise ScenarioError(f"planning needs friction in both directions, got mu_x = {scenario.mu_x}, "
                            f"mu_y = {scenario.mu_y}")
    x = _number("plan.x", table["x"])
    y = _number("plan.y", table["y"])
    yaw_targeted = "yaw_deg" in table
    yaw = math.radians(_number("plan.yaw_deg", table["yaw_deg"], lo=-180.0, hi=180.0)) if yaw_targeted else 0.0
    steps = _integer("plan.steps", table["steps"], 1)
    max_step = _number("plan.max_step", table["max_step"], positive=True)
    if yaw_targeted:
        if "max_dtheta_deg" not in table:
            raise ScenarioError("missing key plan.max_dtheta_deg (needed with plan.yaw_deg)")
        max_dtheta = math.radians(_number("plan.max_dtheta_deg", table["max_dtheta_deg"], positive=True))
    elif "max_dtheta_deg" in table:
        raise ScenarioError("plan.max_dtheta_deg is only used with plan.yaw_deg (rotation commands)")
    else:
        max_dtheta = 0.0
    travel = math.hypot(x, y)
    if "tolerance" in table:
        tolerance = _number("plan.tolerance", table["tolerance"], positive=True)
    elif travel > 0:
        tolerance = DEFAULT_TOLERANCE_REL * travel
    else:
        raise ScenarioError("plan.tolerance is required when the target position is the start (x = y = 0)")
    yaw_tol = math.radians(_number("plan.yaw_tolerance_deg", table.get("yaw_tolerance_deg", DEFAULT_YAW_TOLERANCE_DEG),
                                   positive=True))
    effort = _number("plan.effort_weight", table.get("effort_weight", DEFAULT_EFFORT_WEIGHT), nonneg=True)
    elements = tuple(_triple("plan.planning_elements", table.get("planning_elements", list(DEFAULT_PLANNING_ELEMENTS)),
                             lambda k, v: _integer(k, v, 1)))
    quadrature = _integer("plan.planning_quadrature", table.get("planning_quadrature", DEFAULT_PLANNING_QUADRATURE), 1)
    if quadrature > 3:
        raise ScenarioError(f"plan.planning_quadrature must be 1, 2 or 3, got {quadrature}")
    rollouts = _integer("plan.max_rollouts", table.get("max_rollouts", DEFAULT_MAX_ROLLOUTS), 1)
    return PlanSpec(target=(x, y, yaw), yaw_targeted=yaw_targeted, steps=steps, max_step=max_step,
                    max_dtheta=max_dtheta, tolerance=tolerance, yaw_tolerance=yaw_tol, effort_weight=effort,
                    planning_elements=elements, planning_quadrature=quadrature, max_rollouts=rollouts)


def press_commands(scenario: Scenario) -> tuple[Command, ...]:
    """The scenario's ``[[load]]`` entries, checked to be a press (``dz`` only, net compression).

    Raises
    ------
    ScenarioError
    """
    cmds = scenario.commands
    if not cmds:
        raise ScenarioError("a planning scenario needs [[load]] entries pressing the block (dz < 0)")
    for i, c in enumerate(cmds):
        if c.dx or c.dy or c.dtheta:
            raise ScenarioError(f"load[{i}] moves the upper face in the plane; the [[load]] entries of a "
                                "planning scenario are the press (dz only)")
    if sum(c.dz for c in cmds) >= 0:
        raise ScenarioError("the [[load]] entries must press the block (total dz < 0)")
    return cmds


def naive_commands(spec: PlanSpec) -> np.ndarray:
    """The baseline: the upper face moved straight by the target pose in K equal steps, (K, 3)."""
    t = np.array(spec.target) * np.array([1.0, 1.0, float(spec.yaw_targeted)])
    return np.tile(t / spec.steps, (spec.steps, 1))


def pose_error(pose, spec: PlanSpec) -> tuple[float, float]:
    """Position error (m) and absolute yaw error (rad, 0 without a yaw target) of a final pose."""
    e = np.asarray(pose, float)[:2] - spec.target[:2]
    yaw = abs(float(_wrap(pose[2] - spec.target[2]))) if spec.yaw_targeted else 0.0
    return float(np.hypot(*e)), yaw


def within_tolerance(pose, spec: PlanSpec) -> bool:
    pos, yaw = pose_error(pose, spec)
    return pos <= spec.tolerance and yaw <= spec.yaw_tolerance


# -- FE adapter ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Rollout:
    """An FE rollout of planned commands from the pressed state.

    ``lower`` / ``upper``: (K + 1, 3) face poses ``(x, y, yaw)`` (m, rad); row 0 after
    the press.  ``reports``: the K step reports.
    """

    commands: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    reports: tuple[StepReport, ...]
    wall_time: float


class FeRollouts:
    """The FE model on one mesh, pressed once; every rollout branches from the pressed state
    (``step`` never mutates a state).  Counts rollouts; times the press."""

    def __init__(self, model: Model, press: tuple[Command, ...], label: str):
        self.model = model
        self.press = press
        self.label = label
        self.count = 0
        self.press_time = 0.0
        self._pressed: tuple[State, tuple[StepReport, ...]] | None = None

    def _run(self, state: State, commands) -> tuple[State, list[StepReport]]:
        reports = []
        for c in commands:
            state, rep = step(self.model, state, c)
            if not rep.converged:
                raise PlanningError(f"FE step {rep.step_index} on the {self.label} mesh failed "
                                    f"({rep.status.value}): {rep.message}")
            reports.append(rep)
        return state, reports

    def pressed(self) -> tuple[State, tuple[StepReport, ...]]:
        """State after the press and the press reports (computed once)."""
        if self._pressed is None:
            t0 = time.perf_counter()
            state, reports = self._run(initial_state(self.model), self.press)
            self._pressed = (state, tuple(reports))
            self.press_time = time.perf_counter() - t0
        return self._pressed

    def rollout(self, commands: np.ndarray) -> Rollout:
        """Apply (K, 3) commands ``(dx, dy, dtheta)`` after the press.

        Raises
        ------
        PlanningError
            An FE step did not converge.
        """
        state0, press = self.pressed()
        t0 = time.perf_counter()
        cmds = [Command(dx=float(c[0]), dy=float(c[1]), dtheta=float(c[2])) for c in commands]
        states = [state0]
        reports = [press[-1]]
        state = state0
        for c in cmds:
            state, reps = self._run(state, [c])
            states.append(state)
            reports.extend(reps)
        lower = np.array([[*r.lower_centroid[:2], r.lower_yaw] for r in reports])
        upper = np.array([[*s.upper_translation[:2], s.upper_rotation] for s in states])
        wall = time.perf_counter() - t0
        self.count += 1
        return Rollout(np.array(commands, float), lower, upper, tuple(reports[1:]), wall)


# -- transcription and solver --------------------------------------------------------------
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
    units of ``max_step``).  Poses follow explicitly: the lower face slips along the
    surface normal, the upper face leads it by the elastic lag.
    """

    def __init__(self, params: PushParameters, spec: PlanSpec):
        import casadi as ca

        if spec.yaw_targeted and not params.rotation:
            raise ValueError("a yaw target needs a reduced model with torsional parameters")
        self.params, self.spec = params, spec
        K, d = spec.steps, (3 if spec.yaw_targeted else 2)
        opti = ca.Opti()
        A = opti.variable(d, K)
        rho = opti.variable(1, K)
        sigma = opti.variable(1, K)
        target = opti.parameter(3)
        modifier = opti.parameter(3)
        R = ca.DM(params.frame)
        N, mx, my = params.normal_force, params.mu_x, params.mu_y
        mbar = math.sqrt(mx * my)
        lower, upper, cmds = [ca.DM.zeros(3, 1)], [ca.DM.zeros(3, 1)], []
        effort = 0
        for k in range(K):
            a = A[:, k]
            slip_xy = spec.max_step * sigma[k] * (R @ ca.vertcat(mbar * a[0] / mx, mbar * a[1] / my))
            lag_xy = params.compliance * rho[k] * N * (R @ ca.vertcat(mx * a[0], my * a[1]))
            if spec.yaw_targeted:
                slip_th = spec.max_step * sigma[k] * mbar * a[2] * N / params.max_torque
                lag_th = params.torsion_compliance * rho[k] * params.max_torque * a[2]
            else:
                slip_th = lag_th = 0
            p = lower[-1] + ca.vertcat(slip_xy, slip_th)
            u = p + ca.vertcat(lag_xy, lag_th)
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
    """Largest difference (m or rad) between the NLP's lower-face poses and the reduced
    model re-simulated with the NLP's commands (the complementarity check)."""
    cmds = solution.commands.copy()
    if not params.rotation:
        cmds[:, 2] = 0.0
    traj = simulate_reduced(params, cmds)
    return float(np.abs(traj.lower - solution.lower).max())


# -- the planning loop ----------------------------------------------------------------------
@dataclass
class PlanResult:
    """Everything ``plan.json`` reports (see :func:`plan_document`)."""

    scenario: Scenario
    spec: PlanSpec
    status: str  # "converged", "infeasible" or "not_converged"
    message: str
    params: PushParameters
    solution: NlpSolution
    planning: Rollout | None
    verified: Rollout
    naive: Rollout
    modifier: np.ndarray
    iterations: list[dict]
    rollouts: dict
    timings: dict
    press_reports: tuple[StepReport, ...]

    @property
    def commands(self) -> np.ndarray:
        return self.verified.commands


def _log_line(log, text: str) -> None:
    if log is not None:
        log(text)


def plan(scenario: Scenario, spec: PlanSpec | None = None, log=None) -> PlanResult:
    """Plan the commands of the scenario's ``[plan]`` table (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        Its ``[block]`` mesh is the verification mesh; ``[[load]]`` is the press.
    spec : PlanSpec, optional
        Defaults to ``parse_plan(scenario)``.
    log : callable(str), optional
        Receives one line per phase / iteration.

    Raises
    ------
    ScenarioError
        Bad ``[plan]`` table or press.
    PlanningError
        An FE step failed.
    """
    t_start = time.perf_counter()
    spec = spec or parse_plan(scenario)
    press = press_commands(scenario)
    timings = {"calibration": 0.0, "nlp": 0.0, "planning_rollouts": 0.0, "verification_rollouts": 0.0,
               "naive_verification": 0.0}
    message = ""
    if not spec.reachable:
        message = (f"target {spec.travel * 1e3:.4g} mm"
                   + (f" / {math.degrees(spec.target[2]):.4g} deg" if spec.yaw_targeted else "")
                   + f" is beyond reach of {spec.steps} steps of {spec.max_step * 1e3:.4g} mm"
                   + (f" / {math.degrees(spec.max_dtheta):.4g} deg" if spec.yaw_targeted else "")
                   + "; planning the closest reachable pose")
        _log_line(log, "warning: " + message)

    coarse = FeRollouts(scenario.model(elements=spec.planning_elements, quadrature=spec.planning_quadrature),
                        press, "planning")
    fine = FeRollouts(scenario.model(), press, "verification")
    naive = naive_commands(spec)

    t0 = time.perf_counter()
    calib = coarse.rollout(naive)
    twist = None
    if spec.yaw_targeted:
        twist = coarse.rollout(np.tile([0.0, 0.0, spec.max_dtheta], (spec.steps, 1)))
    params = calibrate(coarse.model, calib.reports, twist.reports if twist else None)
    timings["calibration"] = time.perf_counter() - t0
    _log_line(log, f"calibrated on {coarse.label} mesh {spec.planning_elements}: compliance "
                   f"{params.compliance:.4g} m/N, normal force {params.normal_force:.5g} N"
              + (f", torsion compliance {params.torsion_compliance:.4g} rad/(N m), max torque "
                 f"{params.max_torque:.4g} N m" if params.rotation else ""))

    planner = ReducedPlanner(params, spec)
    modifier = np.zeros(3)
    solution: NlpSolution | None = None
    iterations: list[dict] = []
    planning_rollout = None
    best: tuple[float, Rollout, NlpSolution, np.ndarray] | None = None
    for phase, fe in (("planning", coarse), ("verification", fine)):
        previous_error = math.inf
        for j in range(spec.max_rollouts):
            resolve = solution is None or not (phase == "verification" and j == 0)
            if resolve:
                solution = planner.solve(modifier, warm=solution)
                timings["nlp"] += solution.wall_time
            roll = fe.rollout(solution.commands)
            timings[f"{phase}_rollouts"] += roll.wall_time
            used_modifier = modifier
            modifier = roll.lower[-1] - solution.lower[-1]
            pos_err, yaw_err = pose_error(roll.lower[-1], spec)
            iterations.append({
                "phase": phase, "rollout": j + 1, "resolved": resolve, "nlp_iterations": solution.iterations,
                "nlp_success": solution.success, "nlp_status": solution.return_status,
                "objective": solution.objective, "modifier_used": used_modifier.tolist(),
                "position_error": pos_err, "yaw_error_deg": math.degrees(yaw_err),
                "model_consistency": model_consistency(params, solution),
                "rollout_wall_s": roll.wall_time, "nlp_wall_s": solution.wall_time if resolve else 0.0,
            })
            _log_line(log, f"{phase:>12} rollout {j + 1}: position error {pos_err * 1e3:.5f} mm "
                           f"({100 * pos_err / max(spec.travel, 1e-300):.3f} % of travel)"
                      + (f", yaw error {math.degrees(yaw_err):.4f} deg" if spec.yaw_targeted else "")
                      + f", ipopt {solution.iterations} it {'ok' if solution.success else solution.return_status}")
            if phase == "planning":
                planning_rollout = roll
            else:
                score = pos_err / spec.tolerance + yaw_err / spec.yaw_tolerance
                if best is None or score < best[0]:
                    best = (score, roll, solution, used_modifier)
            if within_tolerance(roll.lower[-1], spec):
                break
            if not spec.reachable and abs(previous_error - pos_err) < NO_PROGRESS * spec.tolerance:
                break
            previous_error = pos_err

    _, verified, solution, final_modifier = best
    t0 = time.perf_counter()
    naive_roll = fine.rollout(naive)
    timings["naive_verification"] = time.perf_counter() - t0
    timings["press"] = coarse.press_time + fine.press_time
    timings["total"] = time.perf_counter() - t_start
    if not spec.reachable:
        status = "infeasible"
    elif within_tolerance(verified.lower[-1], spec):
        status = "converged"
        message = "FE-verified final pose within tolerance"
    else:
        status = "not_converged"
        message = (f"FE-verified final pose not within tolerance after {spec.max_rollouts} rollouts per mesh; "
                   "the best verified plan is reported")
    return PlanResult(
        scenario=scenario, spec=spec, status=status, message=message, params=params, solution=solution,
        planning=planning_rollout, verified=verified, naive=naive_roll, modifier=final_modifier,
        iterations=iterations, rollouts={"planning": coarse.count, "verification": fine.count},
        timings=timings, press_reports=fine.pressed()[1],
    )


# -- output -------------------------------------------------------------------------------
def _poses_json(poses: np.ndarray) -> list[list[float]]:
    """(n, 3) poses as ``[x, y, yaw_deg]`` rows."""
    p = np.asarray(poses, float)
    return [[float(r[0]), float(r[1]), math.degrees(float(r[2]))] for r in p]


def _error_json(pose, spec: PlanSpec) -> dict:
    pos, yaw = pose_error(pose, spec)
    return {"position": pos, "position_rel_travel": pos / spec.travel if spec.travel > 0 else None,
            "yaw_deg": math.degrees(yaw) if spec.yaw_targeted else None}


def _commands_json(commands: np.ndarray) -> list[dict]:
    return commands_to_json([Command(dx=c[0], dy=c[1], dtheta=c[2]) for c in commands])


def plan_commands_json(result: PlanResult) -> list[dict]:
    """The re-executable command list (press, then planned commands)."""
    return commands_to_json([r.command for r in result.press_reports]) + _commands_json(result.commands)


def plan_document(result: PlanResult) -> dict:
    """The ``plan.json`` content.

    ``commands`` is the full re-executable sequence (press, then the K planned
    commands) in the :mod:`pushplan.plan_io` format; poses are lists of
    ``[x (m), y (m), yaw (deg)]`` of the lower face, row 0 after the press, row k
    after planned command k (simulate step ``press_steps + k``).  ``solver.fe_rollouts``
    counts every rollout per mesh: calibration, correction and the naive baseline.
    """
    spec = result.spec
    sol = result.solution
    return {
        "scenario": result.scenario.to_dict(),
        "plan": spec.to_dict(),
        "status": result.status,
        "message": result.message,
        "commands": plan_commands_json(result),
        "press_steps": len(result.press_reports),
        "planned_commands": _commands_json(result.commands),
        "poses": {
            "predicted": _poses_json(sol.lower),
            "predicted_upper": _poses_json(sol.upper),
            "planning_fe": _poses_json(result.planning.lower) if result.planning is not None else None,
            "verified": _poses_json(result.verified.lower),
            "verified_upper": _poses_json(result.verified.upper),
        },
        "modifier": {"x": float(result.modifier[0]), "y": float(result.modifier[1]),
                     "yaw_deg": math.degrees(float(result.modifier[2]))},
        "final_error": _error_json(result.verified.lower[-1], spec),
        "naive": {
            "commands": _commands_json(result.naive.commands),
            "verified_poses": _poses_json(result.naive.lower),
            "final_error": _error_json(result.naive.lower[-1], spec),
        },
        "reduced_model": result.params.to_dict(),
        "meshes": {
            "planning": {"elements": list(spec.planning_elements), "quadrature": spec.planning_quadrature},
            "verification": {"elements": list(result.scenario.elements), "quadrature": result.scenario.quadrature},
        },
        "solver": {
            "nlp": "casadi Opti + ipopt",
            "nlp_solves": sum(1 for it in result.iterations if it["resolved"]),
            "nlp_success": sol.success,
            "nlp_iterations": sol.iterations,
            "fe_rollouts": result.rollouts,
            "wall_time_s": result.timings,
            "iterations": result.iterations,
        },
        "release": "not modelled: poses are under load, upper face held after the last command",
    }


def write_recording(result: PlanResult, path, verification_model: Model) -> None:
    """``recording.rrd``: the verified FE rollout (press and plan) and the plan overlays."""
    from ..outputs.recording import Recorder
    from ..run.summary import StepSummary

    spec = result.spec
    cost = [it["objective"] for it in result.iterations]
    resolved = result.scenario.to_dict()
    resolved["load"] = plan_commands_json(result)
    with Recorder(path, f"plan_{result.scenario.name}", verification_model.mesh, scenario=resolved) as rec:
        for rep in (*result.press_reports, *result.verified.reports):
            rec.log_step(rep, StepSummary.from_report(rep))
        dims = 3 if spec.yaw_targeted else 2
        rec.log_plan(target=np.array(spec.target)[:dims], predicted=result.solution.lower[:, :dims],
                     verified=result.verified.lower[:, :dims], naive=result.naive.lower[:, :dims], cost=cost)


# -- CLI ----------------------------------------------------------------------------------
def cmd_plan(args) -> int:
    from ..errors import EXIT_SOLVER_FAILURE
    from ..outputs.atomic import atomic_write_json, prepare_output_dir
    from ..config.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    spec = parse_plan(scenario)
    out = prepare_output_dir(args.out)

    def log(text):
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    try:
        result = plan(scenario, spec, log=log)
    except PlanningError as exc:
        print(f"pushplan: solver failure: {exc}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    doc = plan_document(result)
    atomic_write_json(out / "plan.json", doc)
    wrote = [out / "plan.json"]
    if not args.no_recording:
        write_recording(result, out / "recording.rrd", scenario.model())
        wrote.append(out / "recording.rrd")
    fe, nv = doc["final_error"], doc["naive"]["final_error"]

    def describe(e):
        rel = f" ({100 * e['position_rel_travel']:.3f} % of travel)" if e["position_rel_travel"] is not None else ""
        yaw = f", yaw {e['yaw_deg']:.4f} deg" if e["yaw_deg"] is not None else ""
        return f"{e['position'] * 1e3:.5f} mm{rel}{yaw}"

    print(f"{scenario.name}: {result.status} ({result.message})")
    print(f"  planned final error (FE, verification mesh): {describe(fe)}")
    print(f"  naive final error   (FE, verification mesh): {describe(nv)}")
    print(f"  FE rollouts: planning {result.rollouts['planning']}, verification {result.rollouts['verification']}; "
          f"plan time {result.timings['total']:.2f} s")
    print("  wrote " + ", ".join(str(p) for p in wrote))
    if result.status == "infeasible":
        print(f"pushplan: {result.message}", file=sys.stderr)
    if result.status == "not_converged":
        print(f"pushplan: {result.message}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def register(subparsers) -> None:
    """Add the ``plan`` subcommand."""
    p = subparsers.add_parser("plan", help="plan upper-face commands reaching a target pose ([plan] table)")
    p.add_argument("scenario", help="scenario TOML file with a [plan] table")
    p.add_argument("--out", required=True, help="output folder (plan.json, recording.rrd)")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_plan)
