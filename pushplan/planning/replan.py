"""Re-planning from a measured state (``pushplan plan --from OBSERVATIONS``).

The observation file holds the commands executed so far (the press, then ``k`` planned
pushes) and the lower-face pose observed after each.  The remaining ``K - k`` pushes are
planned from the FE state those commands leave in the model, to move the lower face by
what remains as measured, ``target - observed``: the model's error so far is taken to
persist as an offset (the usual modifier of the correction loop, here measured on the
real block).  Poses of the re-plan are relative to the observed pose.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Command

from ..config.observations import Observations, leading_press
from ..config.plan import PlanSpec, press_commands
from ..config.scenario import Scenario
from ..errors import InputError
from .planner import PlanSession, plan


@dataclass(frozen=True)
class Start:
    """A measured state: executed in-plane commands after the press and the last observed
    lower-face pose ``(x, y, yaw)`` (m, rad) from rest."""

    executed: tuple[Command, ...]
    observed: np.ndarray

    def to_dict(self) -> dict:
        x, y, yaw = (float(v) for v in self.observed)
        return {"executed_pushes": len(self.executed), "observed_pose": [x, y, math.degrees(yaw)]}


def _same(a: Command, b: Command) -> bool:
    return all(math.isclose(u, v, rel_tol=1e-9, abs_tol=1e-15)
               for u, v in zip((a.dx, a.dy, a.dz, a.dtheta), (b.dx, b.dy, b.dz, b.dtheta), strict=True))


def measured_start(scenario: Scenario, spec: PlanSpec, obs: Observations) -> Start:
    """The start of a re-plan from ``obs``.

    Raises
    ------
    InputError
        The file does not start with the scenario's press, lacks the pose columns
        (``lower_yaw_deg`` too for a yaw target), has executed every planned step, or an
        executed push is beyond the step bounds (:meth:`PlanSpec.check_steps`, as the
        service's ``Replan`` refuses it: the re-plan continues from those pushes as if the
        planner could have commanded them), naming its row and value.
    """
    press = press_commands(scenario)
    observed_press = leading_press(obs)
    if len(observed_press) != len(press) or not all(map(_same, observed_press, press)):
        raise InputError(f"observations: the first rows must be the scenario's press ({len(press)} dz-only rows "
                         f"as in its [[load]]), got {len(observed_press)} dz-only rows that differ")
    needed = ("lower_x", "lower_y") + (("lower_yaw_deg",) if spec.yaw_targeted else ())
    for k in needed:
        if k not in obs.values:
            raise InputError(f"observations: re-planning needs the observed pose, missing column {k}")
    executed = obs.commands[len(press):]
    if len(executed) >= spec.steps:
        raise InputError(f"observations: {len(executed)} pushes executed, plan.steps = {spec.steps}: nothing to re-plan")

    def row(k):  # the file's row (counted from 1, the press first) and columns
        c = executed[k]
        return (f"observations: row {len(press) + k + 1} [dx, dy, dtheta_deg] = "
                f"[{c.dx!r}, {c.dy!r}, {math.degrees(c.dtheta):.12g}]")
    spec.check_steps([(c.dx, c.dy, c.dtheta) for c in executed], "executed", name=row)
    yaw = math.radians(obs.values["lower_yaw_deg"][-1]) if "lower_yaw_deg" in obs.values else 0.0
    return Start(executed, np.array([obs.values["lower_x"][-1], obs.values["lower_y"][-1], yaw]))


def remaining_spec(spec: PlanSpec, start: Start) -> PlanSpec:
    """The ``[plan]`` of the remaining steps: the target less the observed pose."""
    target = np.array(spec.target) - start.observed * np.array([1.0, 1.0, float(spec.yaw_targeted)])
    return dataclasses.replace(spec, target=tuple(float(v) for v in target), steps=spec.steps - len(start.executed))


def replan(scenario: Scenario, spec: PlanSpec, obs: Observations, log=None, baseline: bool = True,
           session: PlanSession | None = None):
    """Plan the remaining steps from the state of ``obs``; returns ``(PlanResult, Start)``
    (``baseline``: see :func:`~pushplan.planning.planner.plan`).

    Cold (a new :func:`plan` from the press), or warm in ``session`` (built once for
    ``scenario`` and a spec with the same bounds), which first executes the pushes of
    ``obs`` it has not executed, one FE step each."""
    start = measured_start(scenario, spec, obs)
    if session is None:
        return plan(scenario, remaining_spec(spec, start), log=log, after=start.executed, baseline=baseline), start
    session.continue_from(start.executed)
    return session.plan(remaining_spec(spec, start), baseline=baseline), start
