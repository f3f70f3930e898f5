"""The planning loop: upper-face commands that bring the block's lower face to a
target pose, planned on a reduced model and corrected with FE rollouts.

Strategy (docs/planning.md explains why):

1. Calibrate :mod:`.reduced_model` from FE rollouts on the coarse planning mesh:
   the naive push (also the baseline) gives the shear compliance and the normal
   force; for a yaw target, a pure rotation gives the torsional compliance and the
   torque of torsional sliding.
2. Solve the planning NLP on the reduced model (:mod:`.nlp`).
3. Modifier adaptation: roll the plan out in the FE model (:mod:`.rollouts`), add
   the FE-minus-model final-pose mismatch to the NLP's prediction and re-solve,
   until the FE pose is within tolerance.  First on the planning mesh, then on the
   verification mesh (the scenario's ``[block]`` mesh), whose best rollout is the
   reported result.

The scenario's ``[[load]]`` entries are the press; the ``[plan]`` table is read by
:mod:`pushplan.config.plan`.  ``target_state`` says which pose the target is for:
``"loaded"`` (upper face still held after the last command) or ``"rest"`` (after
the scenario's ``[release]``).  For a rest target every rollout runs the release,
and the reduced model predicts the rest pose with the spring-back of the lag
(:mod:`.springback`) calibrated on the naive rollout.

``parse_plan``, ``plan_commands_json`` and ``plan_document`` are re-exported here for
callers of the earlier flat module.
"""

from __future__ import annotations

import math
import time
from typing import Callable, NamedTuple

import numpy as np

from ..config.plan import PlanSpec, parse_plan, press_commands
from ..config.scenario import Scenario
from .document import plan_commands_json, plan_document
from .nlp import NlpSolution, ReducedPlanner, model_consistency
from .reduced_model import PushParameters, calibrate
from .result import Iteration, PlanResult
from .rollouts import FeRollouts, Rollout
from .springback import Springback, calibrate_springback
from .target import naive_commands, pose_error, reach_message, within_tolerance

__all__ = ["NO_PROGRESS", "plan", "parse_plan", "plan_commands_json", "plan_document"]

NO_PROGRESS = 0.1
"""An infeasible plan stops when the error changes by less than this fraction of the tolerance."""
PHASE_TIMINGS = ("calibration", "nlp", "planning_rollouts", "verification_rollouts", "naive_verification")


def _log_line(log, text: str) -> None:
    if log is not None:
        log(text)


class _Best(NamedTuple):
    """The best verified rollout so far and the solve behind it."""

    score: float  # position plus yaw error, each in units of its tolerance
    rollout: Rollout
    solution: NlpSolution
    modifier: np.ndarray


class _Correction:
    """Modifier adaptation across the planning and the verification mesh.

    Holds the NLP (re-solved with the last FE-minus-model mismatch), the iteration
    log, the last planning-mesh rollout and the best verification-mesh rollout.
    """

    def __init__(self, planner: ReducedPlanner, timings: dict, log: Callable[[str], None] | None):
        self.planner, self.spec, self.timings, self.log = planner, planner.spec, timings, log
        self.modifier = np.zeros(3)
        self.solution: NlpSolution | None = None
        self.iterations: list[Iteration] = []
        self.planning: Rollout | None = None
        self.best: _Best | None = None

    def run(self, phase: str, fe: FeRollouts) -> None:
        """Up to ``max_rollouts`` rollouts on ``fe``'s mesh; the first verification
        rollout re-checks the planning mesh's last plan without a re-solve."""
        previous_error = math.inf
        for j in range(self.spec.max_rollouts):
            roll, pos_err = self._iterate(phase, fe, j)
            if within_tolerance(roll.final(self.spec.target_state), self.spec):
                break
            if not self.spec.reachable and abs(previous_error - pos_err) < NO_PROGRESS * self.spec.tolerance:
                break
            previous_error = pos_err

    def _iterate(self, phase: str, fe: FeRollouts, j: int) -> tuple[Rollout, float]:
        """One (re-solve and) rollout; returns it and its final position error."""
        spec = self.spec
        resolve = self.solution is None or not (phase == "verification" and j == 0)
        if resolve:
            self.solution = self.planner.solve(self.modifier, warm=self.solution)
            self.timings["nlp"] += self.solution.wall_time
        solution = self.solution
        roll = fe.rollout(solution.commands)
        self.timings[f"{phase}_rollouts"] += roll.wall_time
        used_modifier = self.modifier
        final = roll.final(spec.target_state)
        self.modifier = final - self.planner.predicted_final(solution)
        pos_err, yaw_err = pose_error(final, spec)
        it = Iteration(
            phase=phase, rollout=j + 1, resolved=resolve, nlp_iterations=solution.iterations,
            nlp_success=solution.success, nlp_status=solution.return_status, objective=solution.objective,
            modifier_used=tuple(float(v) for v in used_modifier), position_error=pos_err,
            yaw_error_deg=math.degrees(yaw_err), model_consistency=model_consistency(self.planner.params, solution),
            rollout_wall_s=roll.wall_time, nlp_wall_s=solution.wall_time if resolve else 0.0,
        )
        self.iterations.append(it)
        _log_line(self.log, _iteration_line(it, spec))
        if phase == "planning":
            self.planning = roll
        else:
            score = pos_err / spec.tolerance + yaw_err / spec.yaw_tolerance
            if self.best is None or score < self.best.score:
                self.best = _Best(score, roll, solution, used_modifier)
        return roll, pos_err


def _iteration_line(it: Iteration, spec: PlanSpec) -> str:
    return (f"{it.phase:>12} rollout {it.rollout}: position error {it.position_error * 1e3:.5f} mm "
            f"({100 * it.position_error / max(spec.travel, 1e-300):.3f} % of travel)"
            + (f", yaw error {it.yaw_error_deg:.4f} deg" if spec.yaw_targeted else "")
            + f", ipopt {it.nlp_iterations} it {'ok' if it.nlp_success else it.nlp_status}")


def _calibrate(coarse: FeRollouts, spec: PlanSpec, naive: np.ndarray, log) -> tuple[PushParameters, Springback]:
    """The reduced model fitted to the naive push (and for a yaw target a pure rotation)
    on the planning mesh from the pressed block at rest (its compliances are the block's,
    whatever was executed before a re-plan), and the spring-back of its release."""
    calib = coarse.rollout(naive, release=spec.target_state == "rest")
    springback = Springback(0.0, 0.0)
    if calib.rest is not None:
        springback = calibrate_springback(calib.lower[-1], calib.upper[-1], calib.rest)
        _log_line(log, f"release spring-back: {springback.position:.4g} of the lag in position, "
                       f"{springback.yaw:.4g} in yaw")
    twist = None
    if spec.yaw_targeted:
        twist = coarse.rollout(np.tile([0.0, 0.0, spec.max_dtheta], (spec.steps, 1)), release=False)
    params = calibrate(coarse.model, calib.reports, twist.reports if twist else None, log=log)
    _log_line(log, f"calibrated on {coarse.label} mesh {spec.planning_elements}: compliance "
                   f"{params.compliance:.4g} m/N, normal force {params.normal_force:.5g} N"
              + (f", torsion compliance {params.torsion_compliance:.4g} rad/(N m), max torque "
                 f"{params.max_torque:.4g} N m" if params.rotation else ""))
    return params, springback


def _start_lag(fe: FeRollouts) -> np.ndarray:
    """``upper - lower`` (m, m, rad) of the state a re-plan starts from (after the executed pushes)."""
    pressed = fe.pressed()
    rep = pressed.reports[-1]
    return np.array([*rep.lag, pressed.state.upper_rotation - rep.lower_yaw])


def _status(spec: PlanSpec, verified: Rollout, reach: str) -> tuple[str, str]:
    """The plan's status and message (``reach``: :func:`~.target.reach_message`)."""
    if not spec.reachable:
        return "infeasible", reach
    if within_tolerance(verified.final(spec.target_state), spec):
        return "converged", "FE-verified final pose within tolerance"
    return "not_converged", (f"FE-verified final pose not within tolerance after {spec.max_rollouts} rollouts "
                             "per mesh; the best verified plan is reported")


def plan(scenario: Scenario, spec: PlanSpec | None = None, log=None, after=(), baseline: bool = True) -> PlanResult:
    """Plan the commands of the scenario's ``[plan]`` table (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        Its ``[block]`` mesh is the verification mesh; ``[[load]]`` is the press.
    spec : PlanSpec, optional
        Defaults to ``parse_plan(scenario)``.
    log : callable(str), optional
        Receives one line per phase / iteration.
    after : sequence of fe_contact.Command, optional
        Commands already executed after the press (:mod:`.replan`): the plan starts
        from the state they leave, its poses relative to that state's lower face.
    baseline : bool
        Also roll the naive commands out on the verification mesh (``result.naive``);
        False leaves ``result.naive`` None and saves that rollout.

    Raises
    ------
    InputError
        Bad ``[plan]`` table or press.
    PlanningError
        An FE step failed.
    """
    t_start = time.perf_counter()
    spec = spec or parse_plan(scenario)
    press = press_commands(scenario)
    timings = dict.fromkeys(PHASE_TIMINGS, 0.0)
    reach = reach_message(spec)
    if reach:
        _log_line(log, "warning: " + reach)
    release = scenario.release  # the rollouts show the rest pose whenever the scenario lets go
    coarse = FeRollouts(scenario.model(elements=spec.planning_elements, quadrature=spec.planning_quadrature,
                                     what="plan.planning_elements"),
                        press, "planning", release=release, after=after)
    fine = FeRollouts(scenario.model(), press, "verification", release=release, after=after)
    naive = naive_commands(spec)
    t0 = time.perf_counter()
    at_rest = coarse if not after else FeRollouts(coarse.model, press, "planning", release=release)
    params, springback = _calibrate(at_rest, spec, naive, log)
    timings["calibration"] = time.perf_counter() - t0

    loop = _Correction(ReducedPlanner(params, spec, springback, _start_lag(coarse) if after else np.zeros(3)),
                       timings, log)
    loop.run("planning", coarse)
    loop.run("verification", fine)

    t0 = time.perf_counter()
    naive_roll = fine.rollout(naive) if baseline else None
    timings["naive_verification"] = time.perf_counter() - t0
    timings["press"] = coarse.press_time + fine.press_time
    timings["total"] = time.perf_counter() - t_start
    best = loop.best
    status, message = _status(spec, best.rollout, reach)
    pressed = fine.pressed()
    return PlanResult(
        scenario=scenario, spec=spec, status=status, message=message, params=params, springback=springback,
        solution=best.solution,
        planning=loop.planning, verified=best.rollout, naive=naive_roll, modifier=best.modifier,
        iterations=tuple(loop.iterations), rollouts={"planning": coarse.count, "verification": fine.count},
        timings=timings, press_reports=pressed.reports, press_steps=pressed.steps,
    )
