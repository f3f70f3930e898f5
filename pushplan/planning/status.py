"""The status of a plan: whether its FE-verified final pose is within the tolerance,
and the one-line message that says why not (a target beyond reach, the rollouts spent,
a pad that slid on the upper face)."""

from __future__ import annotations

from ..config.plan import PlanSpec
from .rollouts import Rollout
from .target import within_tolerance

STATUSES = ("converged", "not_converged", "infeasible")
"""``PlanResult.status``: within tolerance; not within it after the rollouts; target beyond reach."""


def plan_status(spec: PlanSpec, verified: Rollout, reach: str, mesh: str = "verification") -> tuple[str, str]:
    """The plan's status (:data:`STATUSES`) and message.

    Parameters
    ----------
    spec : PlanSpec
        The plan's target, tolerances and rollout cap.
    verified : Rollout
        The best verified rollout.
    reach : str
        :func:`~.target.reach_message` of ``spec`` from its start (empty for a reachable target).
    mesh : str
        The mesh the result was verified on (``"verification"`` or ``"planning"``).
    """
    if reach:
        return "infeasible", reach
    on = "" if mesh == "verification" else f" (on the {mesh} mesh)"
    if within_tolerance(verified.final(spec.target_state), spec):
        return "converged", "FE-verified final pose within tolerance" + on
    message = (f"FE-verified final pose{on} not within tolerance after {spec.max_rollouts} rollouts per mesh; the "
               "best verified plan is reported")
    if verified.pad_slip > spec.tolerance:
        message += (f"; the pad slid {verified.pad_slip * 1e3:.4g} mm on the upper face during the push (the reduced "
                    "model assumes the upper face follows the command): the pad cannot drag the block there, a "
                    "stickier pad (gripper.friction above the floor's) is needed")
    return "not_converged", message
