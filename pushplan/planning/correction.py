"""The FE correction of a plan: the reduced model's plan rolled out in the FE model,
first on the planning mesh, then on the verification mesh, and corrected until the FE
final pose is within tolerance or the rollouts per mesh are spent.

``"modifier"`` (modifier adaptation): the NLP re-solved with the last FE-minus-model
mismatch of the final pose added to its prediction.  ``"exact_gradient"``: after an NLP
solve and its rollout, Gauss-Newton steps on the FE model with the exact Jacobian of the
planning mesh (:mod:`.refine`; on the verification mesh, the planning mesh's at its last
commands: a rollout with derivatives there costs 1.3-1.5 plain ones), the NLP re-solved
with the modifier where a step would leave the bounds or did not reduce the error.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..config.plan import PlanSpec
from .nlp import NlpSolution, ReducedPlanner, model_consistency
from .refine import gauss_newton_commands
from .result import Iteration
from .rollouts import FeRollouts, Rollout
from .target import pose_error, within_tolerance

NO_PROGRESS = 0.1
"""An infeasible plan stops when the error changes by less than this fraction of the tolerance."""
REFINEMENTS = ("modifier", "exact_gradient")
DEFAULT_REFINEMENT = "modifier"


class Best(NamedTuple):
    """The best verified rollout so far and the solve behind it."""

    score: float  # position plus yaw error, each in units of its tolerance
    rollout: Rollout
    solution: NlpSolution
    modifier: np.ndarray


class Correction:
    """The FE correction across the planning and the verification mesh (module docstring).

    Holds the iteration log, the last planning-mesh rollout and the best rollout of the
    ``scored`` mesh; ``timings`` (seconds per phase) is added to in place.
    """

    def __init__(self, planner: ReducedPlanner, timings: dict, log=None, scored: str = "verification",
                 modifier=None, warm: NlpSolution | None = None, method: str = DEFAULT_REFINEMENT,
                 reachable: bool | None = None):
        self.planner, self.spec, self.timings, self.log = planner, planner.spec, timings, log
        # whether the target is within the step bounds of the start (planner's reach_message)
        self.reachable = planner.spec.reachable if reachable is None else reachable
        self.scored, self.method = scored, method  # the phase whose best rollout is the result
        self.modifier = np.zeros(3) if modifier is None else np.asarray(modifier, float)
        self.warm = warm  # where the first solve starts (None: the naive commands)
        self.solution: NlpSolution | None = None
        self.commands: np.ndarray | None = None  # the last commands rolled out
        self.refined: np.ndarray | None = None  # the Gauss-Newton commands of the last rollout
        self.jacobian: np.ndarray | None = None  # (3, m, 3) of the last planning-mesh rollout
        self.score = math.inf  # of the last rollout: errors in units of their tolerances
        self.iterations: list[Iteration] = []
        self.planning: Rollout | None = None
        self.best: Best | None = None

    def run(self, phase: str, fe: FeRollouts) -> None:
        """Up to ``max_rollouts`` rollouts on ``fe``'s mesh; the first verification
        rollout re-checks the planning mesh's last plan without a re-solve."""
        previous_error = math.inf
        self.refined, self.score = None, math.inf
        for j in range(self.spec.max_rollouts):
            roll, pos_err = self._iterate(phase, fe, j)
            if within_tolerance(roll.final(self.spec.target_state), self.spec):
                break
            if not self.reachable and abs(previous_error - pos_err) < NO_PROGRESS * self.spec.tolerance:
                break
            previous_error = pos_err

    def _next_commands(self, phase: str, j: int) -> tuple[np.ndarray, bool, bool]:
        """The commands to roll out, whether the NLP was re-solved for them and whether
        they are a Gauss-Newton step."""
        if self.solution is not None and phase == "verification" and j == 0:
            return self.commands, False, False
        if self.refined is not None:
            return self.refined, False, True
        self.solution = self.planner.solve(self.modifier, warm=self.solution or self.warm)
        self.timings["nlp"] += self.solution.wall_time
        return self.solution.commands, True, False

    def _roll(self, phase: str, fe: FeRollouts, commands: np.ndarray) -> Rollout:
        """The rollout of ``commands`` (with the Jacobian on the planning mesh under ``exact_gradient``)."""
        if self.method == "exact_gradient" and phase == "planning":
            roll, self.jacobian = fe.rollout_with_jacobian(commands)
            if roll.nondifferentiable:  # a contact at a transition: no Gauss-Newton step from here
                self.jacobian = None
                if self.log is not None:
                    self.log(f"no exact gradient at these commands: {roll.nondifferentiable}")
        else:  # on the verification mesh: the planning mesh's Jacobian at its last commands
            roll = fe.rollout(commands)
        self.timings[f"{phase}_rollouts"] += roll.wall_time
        return roll

    def _iterate(self, phase: str, fe: FeRollouts, j: int) -> tuple[Rollout, float]:
        """One (re-solve or Gauss-Newton step and) rollout; returns it and its final position error."""
        spec = self.spec
        commands, resolve, newton = self._next_commands(phase, j)
        solution, self.commands = self.solution, commands
        roll = self._roll(phase, fe, commands)
        used_modifier = self.modifier
        final = roll.final(spec.target_state)
        if not newton:  # the modifier is of the NLP's own commands
            self.modifier = final - self.planner.predicted_final(solution)
        pos_err, yaw_err = pose_error(final, spec)
        score = pos_err / spec.tolerance + yaw_err / spec.yaw_tolerance
        progress = not newton or score < self.score
        self.score = score
        self.refined = None  # a Gauss-Newton step that did not improve: the NLP with the modifier next
        if self.jacobian is not None and progress:
            self.refined = gauss_newton_commands(commands, final, self.jacobian, spec)
        it = Iteration(
            phase=phase, rollout=j + 1, resolved=resolve, nlp_iterations=solution.iterations,
            nlp_success=solution.success, nlp_status=solution.return_status, objective=solution.objective,
            modifier_used=tuple(float(v) for v in used_modifier), position_error=pos_err,
            yaw_error_deg=math.degrees(yaw_err), model_consistency=model_consistency(self.planner.params, solution, self.planner.law),
            rollout_wall_s=roll.wall_time, nlp_wall_s=solution.wall_time if resolve else 0.0, gauss_newton=newton,
            not_differentiable=roll.nondifferentiable,
        )
        self.iterations.append(it)
        if self.log is not None:
            self.log(iteration_line(it, spec))
        if phase == "planning":
            self.planning = roll
        if phase == self.scored and (self.best is None or score < self.best.score):
            self.best = Best(score, roll, solution, used_modifier)
        return roll, pos_err


def iteration_line(it: Iteration, spec: PlanSpec) -> str:
    """The progress line of one correction iteration."""
    return (f"{it.phase:>12} rollout {it.rollout}: position error {it.position_error * 1e3:.5f} mm "
            f"({100 * it.position_error / max(spec.travel, 1e-300):.3f} % of travel)"
            + (f", yaw error {it.yaw_error_deg:.4f} deg" if spec.yaw_targeted else "")
            + (", Gauss-Newton step" if it.gauss_newton else
               f", ipopt {it.nlp_iterations} it {'ok' if it.nlp_success else it.nlp_status}"))
