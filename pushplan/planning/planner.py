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
   reported result.  With ``refinement = "exact_gradient"``, Gauss-Newton steps with
   the exact Jacobian of the FE final pose instead of the re-solves (:mod:`.refine`).

All of it is a :class:`PlanSession` (this module): :func:`plan` plans one once; the closed
loop keeps one and re-plans in it after each executed push (warm: nothing above is rebuilt).
Its parts live by job: :mod:`.calibration` (step 1 and when a calibration still holds),
:mod:`.correction` (step 3) and :mod:`.status` (the plan's status and message).

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

import dataclasses
import time

import numpy as np

from ..config.plan import PlanSpec, parse_plan, press_commands
from ..config.scenario import Scenario
from ..errors import InputError
from .calibration import CARRY_LAG_FRACTION, calibrate_reduced, predicts_lag, start_lag
from .correction import DEFAULT_REFINEMENT, NO_PROGRESS, REFINEMENTS, Correction
from .document import plan_commands_json, plan_document
from .nlp import NlpSolution, ReducedPlanner
from .result import PlanResult
from .rollouts import FeRollouts
from .status import plan_status
from .target import naive_commands, reach_message, reach_origin

__all__ = ["CARRY_LAG_FRACTION", "DEFAULT_REFINEMENT", "NO_PROGRESS", "REFINEMENTS", "PlanSession", "plan",
           "parse_plan", "plan_commands_json", "plan_document"]

PHASE_TIMINGS = ("calibration", "nlp", "planning_rollouts", "verification_rollouts", "naive_verification")


class PlanSession:
    """The planner's state between the re-plans of a closed loop (issue 32), built once:
    the planning-mesh (and, with ``verify``, the verification-mesh) FE model with its
    compiled kernels and factorisations, the FE state after the press and after each
    executed push (:meth:`advance`: one FE step per push, never re-run from the press),
    the calibrated reduced model and the NLP (built for the scenario's K steps; a
    re-plan of the last m is a re-solve with new parameter values, warm-started from
    the last plan shifted by the executed pushes, with its modifier).

    The calibration is carried over while the reduced model predicts the in-plane FE lag
    ``upper - lower`` after each executed push within :data:`CARRY_LAG_FRACTION` of the
    FE's; else it is re-fitted as a cold re-plan fits it (a naive push of the remaining
    steps from rest) and the NLP rebuilt.

    :func:`plan` is one session planned once (``pushplan plan``, a cold re-plan):
    ``after`` executed commands applied once with the press, both meshes.
    """

    def __init__(self, scenario: Scenario, spec: PlanSpec | None = None, log=None, after=(), verify: bool = True,
                 refinement: str = DEFAULT_REFINEMENT):
        if refinement not in REFINEMENTS:
            raise ValueError(f"refinement must be one of {REFINEMENTS}, got {refinement!r}")
        self.scenario, self.spec, self.log = scenario, spec or parse_plan(scenario), log
        spec = self.spec
        t0 = time.perf_counter()
        press, release = press_commands(scenario), scenario.release  # rollouts show the rest pose when it lets go
        self.coarse = FeRollouts(scenario.model(elements=spec.planning_elements, quadrature=spec.planning_quadrature,
                                              what="plan.planning_elements"), press, "planning", release=release,
                                 keep_first=True,  # an executed push is the first step of the last rollout
                                 warm_steps=True)  # a rollout's steps start from the last rollout's
        self.fine = FeRollouts(scenario.model(), press, "verification", release=release) if verify else None
        self.calibration_time = 0.0
        self.calibrations = self.nlp_builds = 0
        self._counted: dict = {}
        self._press_counted = 0.0
        self._last: tuple[NlpSolution, np.ndarray, int] | None = None  # solution, modifier, pushes since
        self.refinement = refinement
        if refinement == "exact_gradient" and not all(fe.exact for fe in (self.coarse, self.fine) if fe is not None):
            self.refinement = "modifier"  # a release with a retreat: not differentiated
            self._say("refinement: no exact gradient through a release with a retreat; modifier adaptation")
        self._calibrate(spec)
        self.advance(after)
        self.build_time = time.perf_counter() - t0

    def _say(self, text: str) -> None:
        if self.log is not None:
            self.log(text)

    def _calibrate(self, spec: PlanSpec) -> None:
        t0 = time.perf_counter()
        self.params, self.springback = calibrate_reduced(self.coarse, spec, naive_commands(spec), self.log)
        self.nlp = ReducedPlanner(self.params, self.spec, self.springback)
        self.calibrations += 1
        self.nlp_builds += 1
        self.calibration_time += time.perf_counter() - t0

    @property
    def executed(self) -> tuple:
        """The commands executed after the press (fe_contact Commands)."""
        return self.coarse.after

    def advance(self, commands) -> None:
        """Execute pushes (fe_contact Commands) on the session's meshes, one FE step each.

        Raises
        ------
        PlanningError
            A step did not converge.
        """
        commands = tuple(commands)
        if not commands:
            return
        for fe in (self.coarse, self.fine):
            if fe is not None:
                fe.advance(commands)
        if self._last is not None:
            solution, modifier, n = self._last
            self._last = (solution, modifier, n + len(commands))

    def _rollouts_since(self) -> dict:
        """FE rollouts per mesh since the last plan (the first plan: since the start,
        the calibration's included)."""
        now = {"planning": self.coarse.count, "verification": self.fine.count if self.fine else 0}
        since = {k: v - self._counted.get(k, 0) for k, v in now.items()}
        self._counted = now
        return since

    def follow(self, result: PlanResult) -> None:
        """Continue from ``result``, a plan of this session's spec made elsewhere (the
        closed loop's first plan, on both meshes): its NLP solution warm-starts the
        next re-plan, its modifier starts that re-plan's correction."""
        self._last = (result.solution, np.asarray(result.modifier, float), len(self.executed))

    def carries_calibration(self) -> bool:
        """Whether the reduced model of the last plan predicted the in-plane FE lag after
        the pushes executed since (:func:`~.calibration.predicts_lag`; yes before a plan
        or a push)."""
        if self._last is None or self._last[2] == 0:
            return True
        solution, _, n = self._last
        return predicts_lag(solution, n, self.coarse)

    def continue_from(self, executed) -> None:
        """Execute the pushes of ``executed`` (all pushes after the press, fe_contact
        Commands) that this session has not executed yet.

        Raises
        ------
        InputError
            ``executed`` does not continue the session's pushes.
        """
        executed, done = tuple(executed), self.executed
        if executed[:len(done)] != done:
            raise InputError(f"observations: their {len(executed)} pushes do not continue the "
                             f"{len(done)} this session executed")
        self.advance(executed[len(done):])

    def _start(self, spec: PlanSpec) -> tuple[NlpSolution | None, np.ndarray | None]:
        """Where the correction starts: the last plan shifted by the executed pushes and
        its modifier, or (a calibration that no longer holds) nothing after a re-calibration."""
        if not self.carries_calibration():
            self._say("the reduced model no longer predicts the lag of the executed pushes: re-calibrating")
            self._calibrate(spec)
            return None, None
        if self._last is None:
            return None, None
        solution, modifier, n = self._last
        return dataclasses.replace(solution, variables={k: v[:, n:] for k, v in solution.variables.items()}), modifier

    def plan(self, spec: PlanSpec | None = None, baseline: bool = True, verify: bool = True) -> PlanResult:
        """Plan ``spec`` (default the session's; a re-plan: the remaining steps, target
        relative to the current pose) from the current state; see :func:`plan`.
        ``verify=False`` corrects and scores on the planning mesh alone in a session that
        also holds the verification mesh (as ``closed-loop``'s re-plans)."""
        t_start = time.perf_counter()
        spec = spec or self.spec
        timings = dict.fromkeys(PHASE_TIMINGS, 0.0)
        warm, modifier = self._start(spec)
        timings["calibration"], self.calibration_time = self.calibration_time, 0.0
        lag = start_lag(self.coarse) if self.coarse.relative else np.zeros(3)
        reach = reach_message(spec, reach_origin(spec, lag, self.springback.fractions))
        if reach:
            self._say("warning: " + reach)
        self.nlp.retarget(spec, lag)
        fine = self.fine if verify else None
        scored = "verification" if fine is not None else "planning"
        loop = Correction(self.nlp, timings, self.log, scored, modifier, warm, self.refinement, reachable=not reach)
        loop.run("planning", self.coarse)
        if fine is not None:
            loop.run("verification", fine)
        t0 = time.perf_counter()
        final = fine or self.coarse
        naive_roll = final.rollout(naive_commands(spec)) if baseline else None
        timings["naive_verification"] = time.perf_counter() - t0
        press = self.coarse.press_time + (self.fine.press_time if self.fine else 0.0)
        timings["press"], self._press_counted = press - self._press_counted, press  # and the pushes since
        timings["total"] = time.perf_counter() - t_start
        best = loop.best
        self._last = (best.solution, best.modifier, 0)
        status, message = plan_status(spec, best.rollout, reach, scored)
        pressed = final.pressed()
        return PlanResult(
            scenario=self.scenario, spec=spec, status=status, message=message, params=self.params,
            springback=self.springback, solution=best.solution, planning=loop.planning, verified=best.rollout,
            naive=naive_roll, modifier=best.modifier, iterations=tuple(loop.iterations),
            rollouts=self._rollouts_since(),
            timings=timings, press_reports=pressed.reports, press_steps=pressed.steps, refinement=self.refinement,
        )


def plan(scenario: Scenario, spec: PlanSpec | None = None, log=None, after=(), baseline: bool = True,
         refinement: str = DEFAULT_REFINEMENT) -> PlanResult:
    """Plan the commands of the scenario's ``[plan]`` table (see the module docstring):
    a :class:`PlanSession` planned once.

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
    refinement : str
        The FE correction (:data:`REFINEMENTS`): ``"modifier"`` adaptation, or
        ``"exact_gradient"`` (Gauss-Newton with the exact Jacobian, through the release
        for a rest target; modifier adaptation where the rollouts have no derivatives:
        a release with a retreat).  ``result.refinement`` says which ran; an iteration
        whose rollout had no derivative (a contact at a transition) says why.

    Raises
    ------
    InputError
        Bad ``[plan]`` table or press.
    PlanningError
        An FE step failed.
    """
    return PlanSession(scenario, spec, log, after, refinement=refinement).plan(spec, baseline)
