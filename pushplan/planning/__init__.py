"""Planning pushes: a reduced push model calibrated from FE rollouts, the CasADi
NLP on it, and the correction loop that verifies the plan in the FE model.

``reduced_model``  the block as one elastic-plastic contact spring; calibration
``nlp``            the planning NLP on the reduced model (CasADi ``Opti`` + ipopt)
``rollouts``       FE rollouts from the pressed state through :func:`pushplan.run.drive`
``target``         the naive baseline, pose errors, tolerance test
``planner``        :class:`PlanSession`, the planner's session (the warm planner of the closed
                   loop: re-plans without rebuilding anything); :func:`plan`, one planned once
``calibration``    the reduced model calibrated on FE rollouts; whether it still holds
``correction``     the FE correction loop (modifier adaptation or exact-gradient steps)
``status``         a plan's status and its message
``refine``         the Gauss-Newton step with the exact FE Jacobian (``refinement``)
``result``         :class:`PlanResult`, typed
``document``       ``plan.json`` and ``recording.rrd``
``push_model``     :class:`PushModel`, the FE model as a planner plugin with exact Jacobians
``batch``          :class:`RolloutPool`, warm worker processes for batches of rollouts

Imports nothing from ``mujoco``, ``studies`` or ``cli``; the ``[plan]`` table is
:mod:`pushplan.config.plan`.
"""

from ..config.plan import PlanSpec, parse_plan
from .document import plan_commands_json, plan_document, write_recording
from .planner import PlanSession, plan
from .push_model import PushJacobian, PushModel
from .result import Iteration, PlanResult
from .rollouts import PlanningError, Rollout

__all__ = ["Iteration", "PlanResult", "PlanSession", "PlanSpec", "PlanningError", "PushJacobian", "PushModel", "Rollout",
           "parse_plan", "plan",
           "plan_commands_json", "plan_document", "write_recording"]
