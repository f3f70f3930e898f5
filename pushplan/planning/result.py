"""What a plan produced, as typed data: :class:`PlanResult` and the log of the
correction loop (:class:`Iteration`); :mod:`.document` turns them into ``plan.json``."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from fe_contact import StepReport

from ..config.plan import PlanSpec
from ..config.scenario import Scenario
from ..run import StepSummary
from .nlp import NlpSolution
from .reduced_model import PushParameters
from .rollouts import Rollout
from .springback import Springback

STATUSES = ("converged", "infeasible", "not_converged")


@dataclass(frozen=True)
class Iteration:
    """One FE rollout of the correction loop and the NLP solve behind it.

    ``modifier_used`` is the modifier ``(x, y, yaw)`` (m, rad) the NLP solved with (the
    NLP behind a Gauss-Newton step's commands, ``gauss_newton``);
    errors are of the rollout's final lower-face pose (m, degrees); ``resolved`` is
    false where the previous mesh's plan was rolled out again unchanged.
    """

    phase: str  # "planning" or "verification"
    rollout: int
    resolved: bool
    nlp_iterations: int
    nlp_success: bool
    nlp_status: str
    objective: float
    modifier_used: tuple[float, float, float]
    position_error: float
    yaw_error_deg: float
    model_consistency: float
    rollout_wall_s: float
    nlp_wall_s: float
    gauss_newton: bool = False  # the commands are a Gauss-Newton step on the FE model (exact gradient)
    not_differentiable: str = ""  # the rollout's exact gradient does not exist here: why (a contact at a transition)

    def to_dict(self) -> dict:
        return {**asdict(self), "modifier_used": list(self.modifier_used)}


@dataclass(frozen=True)
class PlanResult:
    """Everything ``plan.json`` reports (see :func:`~pushplan.planning.document.plan_document`).

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`; ``message`` says why.
    solution : NlpSolution
        The NLP solve behind the reported (best verified) plan.
    planning, verified, naive : Rollout
        The last rollout on the planning mesh (None if none), the best one on the
        verification mesh (the result) and the naive baseline on the verification mesh
        (None when planned without it: ``plan(..., baseline=False)``).
    modifier : ndarray, shape (3,)
        The modifier of the reported plan's solve, m and rad.
    rollouts : dict
        FE rollouts per mesh (``planning``, ``verification``).
    timings : dict
        Wall times per phase, s.
    press_reports, press_steps : tuples
        The press on the verification mesh: step reports and their summaries.
    """

    scenario: Scenario
    spec: PlanSpec
    status: str
    message: str
    params: PushParameters
    springback: Springback
    solution: NlpSolution
    planning: Rollout | None
    verified: Rollout
    naive: Rollout | None
    modifier: np.ndarray
    iterations: tuple[Iteration, ...]
    rollouts: dict
    timings: dict
    press_reports: tuple[StepReport, ...]
    press_steps: tuple[StepSummary, ...]
    refinement: str = "modifier"
    """The FE correction: ``"modifier"`` (modifier adaptation) or ``"exact_gradient"``
    (Gauss-Newton steps with the exact Jacobian, :mod:`.refine`)."""

    @property
    def commands(self) -> np.ndarray:
        """The planned commands (K, 3) ``(dx, dy, dtheta)``, m and rad."""
        return self.verified.commands
