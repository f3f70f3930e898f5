"""The closed loop's results, typed (:func:`~pushplan.identify.closed_loop.closed_loop`
returns a :class:`ClosedLoopResult`); dicts only in their ``to_dict`` methods, the
``closed_loop.json`` content (poses ``[x (m), y (m), yaw (deg)]``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Command

from ..config.commands import command_to_dict
from ..config.plan import PlanSpec
from ..config.scenario import Scenario
from ..planning.target import pose_error, within_tolerance
from ..planning.document import POSE_UNITS
from .episodes import Episode, Stop, pose_json
from .fit import Identification


@dataclass(frozen=True)
class RobustReplan:
    """A robust re-plan of the loop (:func:`~pushplan.planning.robust.plan_robust` over the
    re-identified distribution; no Monte Carlo check inside the loop)."""

    level: float
    reached: bool
    predicted_probability: float  # of the commands executed next
    nominal_predicted_probability: float  # of the nominal re-plan's commands
    parameters: tuple[str, ...]  # the distribution's (undetermined ones held at their estimate)
    held: tuple[str, ...]  # undetermined parameters held at the estimate
    evaluations: int
    sigma_point_rollouts: int
    wall_time: float

    def to_dict(self) -> dict:
        return {"level": self.level, "reached": self.reached, "predicted_probability": self.predicted_probability,
                "nominal_predicted_probability": self.nominal_predicted_probability,
                "parameters": list(self.parameters), "held_at_estimate": list(self.held),
                "evaluations": self.evaluations, "sigma_point_rollouts": self.sigma_point_rollouts,
                "wall_time_s": self.wall_time}


@dataclass(frozen=True)
class Iteration:
    """One push of the closed loop: the command executed, the pose observed after it,
    the friction the plan behind it used and, with identification, the estimates (and,
    re-planned robustly, that re-plan's predicted probability)."""

    step: int
    command: Command
    observed: np.ndarray
    friction: dict
    plan_status: str
    plan_message: str  # why the plan behind the push has its status (the bound or tolerance it misses)
    plan_fe_rollouts: int
    identified: Identification | None
    wall_time: float
    planned: np.ndarray  # (n, 3) lower-face path of the plan behind the push, from rest (m, rad)
    robust: RobustReplan | None = None

    def to_dict(self) -> dict:
        return {"step": self.step, "command": command_to_dict(self.command), "observed_pose": pose_json(self.observed),
                "planned_path": [pose_json(p) for p in self.planned],
                "planned_with": self.friction, "plan_status": self.plan_status,
                "plan_message": self.plan_message, "plan_fe_rollouts": self.plan_fe_rollouts,
                "identified": identified_json(self.identified), "wall_time_s": self.wall_time,
                "robust": None if self.robust is None else self.robust.to_dict(),
                "predicted_probability": None if self.robust is None else self.robust.predicted_probability}


def friction_of(sc: Scenario) -> dict:
    """The scenario's friction ellipse as written in ``closed_loop.json``."""
    return {"mu_x": sc.mu_x, "mu_y": sc.mu_y, "angle_deg": sc.angle_deg}


def error_json(pose, spec: PlanSpec) -> dict:
    """A pose's error against the target: position (m), yaw (deg, with a yaw target), within tolerance."""
    pos, yaw = pose_error(pose, spec)
    return {"position": pos, "yaw_deg": math.degrees(yaw) if spec.yaw_targeted else None,
            "within_tolerance": within_tolerance(pose, spec)}


def identified_json(result: Identification | None) -> dict | None:
    """The estimates of one re-identification (sigma None where undetermined)."""
    if result is None:
        return None
    return {k: {"estimate": float(v), "sigma": float(s) if math.isfinite(s) else None, "identifiable": f}
            for k, v, s, f in zip(result.names, result.estimate, result.sigma, result.identifiable, strict=True)} | {
        "fe_rollouts": result.fe_rollouts}


@dataclass(frozen=True)
class TruthRuns:
    """The truth's runs for the recording: the closed loop's (``closed``, a
    :class:`~pushplan.identify.closed_loop.Truth`), the open loop's, and the planned
    path behind each push of the first episode."""

    closed: object
    open: object
    planned: tuple


@dataclass(frozen=True)
class ClosedLoopResult:
    """The closed loop and its open-loop baseline on one truth (poses m, rad)."""

    scenario: Scenario  # the model
    truth: Scenario
    spec: PlanSpec
    identify: bool
    robust: bool
    open_commands: tuple[Command, ...]
    open_final: np.ndarray
    final_pose: np.ndarray
    iterations: tuple[Iteration, ...]
    episodes: tuple[Episode, ...]
    final_estimates: Identification | None
    wall_time: float
    runs: TruthRuns
    stopped: Stop | None = None  # why the episodes stopped before the tolerance or their cap (None: they did not)

    @property
    def within_tolerance(self) -> bool:
        """Whether the closed loop's final pose is within the tolerance."""
        return within_tolerance(self.final_pose, self.spec)

    @property
    def position_error(self) -> float:
        """The closed loop's final position error, m."""
        return pose_error(self.final_pose, self.spec)[0]

    @property
    def open_position_error(self) -> float:
        """The open loop's final position error, m."""
        return pose_error(self.open_final, self.spec)[0]

    def to_dict(self) -> dict:
        """The ``closed_loop.json`` content; every pose row ``[x, y, yaw]`` in ``pose_units``
        (m, m, deg: the service's and the API's poses are in m, m, rad)."""
        spec, rest = self.spec, self.spec.target_state == "rest"
        return {
            "pose_units": list(POSE_UNITS), "scenario": self.scenario.name, "truth": {"name": self.truth.name, **friction_of(self.truth)},
            "model": friction_of(self.scenario), "plan": spec.to_dict(), "identify": self.identify,
            "robust": self.robust,
            "scored_on": "rest pose after the truth's release" if rest else "loaded pose",
            "open_loop": {"commands": [command_to_dict(c) for c in self.open_commands],
                          "final_pose": pose_json(self.open_final), "final_error": error_json(self.open_final, spec)},
            "closed_loop": {"commands": [command_to_dict(it.command) for it in self.iterations],
                            "final_pose": pose_json(self.final_pose),
                            "final_error": error_json(self.final_pose, spec),
                            "episodes": len(self.episodes) or None,
                            "stopped": self.stopped.message if self.stopped else None,
                            "stop": self.stopped.to_dict() if self.stopped else None},
            "final_estimates": identified_json(self.final_estimates),
            "iterations": [it.to_dict() for it in self.iterations],
            "episodes": [e.to_dict() for e in self.episodes],
            "wall_time_s": self.wall_time,
        }
