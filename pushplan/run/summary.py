"""Typed results of a run, built once from the ``fe_contact`` step reports and turned
into dicts only at the file boundary (``summary.json``).

``StepSummary``  the numbers of one converged step (SI units; angles in degrees in
                 the file, radians here), and its ``phase`` (``command`` or ``release``).

Names in ``summary.json`` (per step):

``upper_force``
    N, world frame: the force the gripper applies on the block's upper face, what a
    wrist force sensor between the arm and the hand reads (a press has ``z < 0``).
    The one sign convention of forces (docs/conventions.md): every force is the force
    *on the block*; observation files' ``force_x, _y, _z`` are this one.
``tangential_force``, ``normal_force``
    N: the floor's friction force on the block (world x, y) and its normal force
    (``> 0`` in compression).

``lower_direction_deviation_deg``
    Signed angle from the upper-face to the lower-face in-plane centroid displacement
    (where the lower face went, against where the gripper took the upper face);
    ``null`` while the lower face has not moved (less than
    :data:`DIRECTION_MIN_MOTION` of the upper face's travel: a block that sticks has no
    direction of motion, the terminal shows ``-``).
``twist_deg``
    The same value under its name before issue 33; an alias kept for one release
    (deprecated: read ``lower_direction_deviation_deg``).  The sweep's *lag* angle
    (direction of the upper-minus-lower displacement) is a different quantity,
    ``lag_angle_deg`` in the sweep table.
``pad_slip``
    A frictional pad's slip over the upper face, m: the in-plane distance between the
    pad's commanded position and the upper face's centroid (the offset the pad has slid
    since it touched); ``null`` for a bonded pad, which the upper face follows.
    ``rest.pad_slip`` is that offset at the last step the pad still touched (how far it
    had slid when it let go).  ``warnings`` (top level, when any) holds
    :func:`pad_slip_warning`'s line.
``phase``
    ``command`` for a scenario load step, ``release`` for a step of the release that
    follows; ``rest.step`` (with a release) is the step at which the block is at rest.
``Failure``      the step that failed, its status and message.
``RunStatus``    ``running`` / ``completed`` / ``failed``.
``RestSummary``  where the block came to rest after a release.
``RunSummary``   the scenario as run, the step summaries, status, failure, elapsed time,
                 and the rest pose after a release.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from fe_contact import Command, NodeStatus, Rest, StepReport

from ..config.commands import command_from_dict, command_to_dict

PAD_SLIP_WARN = 0.5
"""A pad that slid more than this fraction of the commanded in-plane travel gets a warning:
it slides over the block rather than dragging it (the reduced model and a bonded gripper
assume it drags)."""
DIRECTION_MIN_MOTION = 0.01
"""Lower-face travel, as a fraction of the upper face's, below which the block sticks and
the lower face's direction deviation (the angle between the two travels) is the
direction of a rounding error: reported as ``null`` / ``-``."""


class RunStatus(str, enum.Enum):
    RUNNING = "running"
    COMPLETED = "completed"
    FAILED = "failed"


@dataclass(frozen=True)
class StepSummary:
    """Numbers of one converged load step (SI units, angles in rad)."""

    step: int
    command: Command
    status: str
    upper_centroid: tuple[float, float, float]
    lower_centroid: tuple[float, float, float]
    lower_yaw: float
    twist: float
    lag: tuple[float, float]
    max_slip: float
    pressure_max: float
    pressure_min: float
    normal_force: float
    tangential_force: tuple[float, float]
    upper_force: tuple[float, float, float]
    equilibrium_error: float
    n_stick: int
    n_slip: int
    n_separated: int
    dissipation: float
    newton_iterations: int
    contact_iterations: int
    newton_residual: float
    contact_residual: float
    min_det_f: float
    wall_time_s: float
    phase: str = "command"
    pad_slip: float | None = None
    """m, a frictional pad's slip over the upper face (module docstring); None when bonded."""

    @property
    def converged(self) -> bool:
        return self.status == "converged"

    @property
    def lower_yaw_deg(self) -> float:
        return math.degrees(self.lower_yaw)

    @property
    def twist_deg(self) -> float:
        return math.degrees(self.twist)

    @property
    def lower_direction_deviation_deg(self) -> float | None:
        """The lower face's direction deviation (``twist``) in degrees, or None while
        the lower face has not moved (:data:`DIRECTION_MIN_MOTION`)."""
        upper = math.hypot(*self.upper_centroid[:2])
        lower = math.hypot(*self.lower_centroid[:2])
        if upper == 0 or lower < DIRECTION_MIN_MOTION * upper:
            return None
        return self.twist_deg

    @classmethod
    def from_report(cls, report: StepReport, phase: str = "command", pad_at=None) -> StepSummary:
        """``pad_at``: the gripper's commanded translation after the step (3,), m (the new
        state's ``upper_translation``), for :attr:`pad_slip`."""
        in_contact = report.node_status != NodeStatus.SEPARATED
        p = report.pressure[in_contact]
        return cls(
            step=report.step_index, command=report.command, status=report.status.value,
            upper_centroid=_floats(report.upper_centroid), lower_centroid=_floats(report.lower_centroid),
            lower_yaw=float(report.lower_yaw), twist=float(report.twist), lag=_floats(report.lag),
            max_slip=float(report.slip.max()),
            pressure_max=float(p.max()) if p.size else 0.0, pressure_min=float(p.min()) if p.size else 0.0,
            normal_force=float(report.normal_force), tangential_force=_floats(report.tangential_force),
            upper_force=_floats(report.upper_force), equilibrium_error=float(report.equilibrium_error),
            n_stick=report.n_stick, n_slip=report.n_slip, n_separated=report.n_separated,
            dissipation=float(report.dissipation), newton_iterations=report.newton_iterations,
            contact_iterations=report.contact_iterations, newton_residual=float(report.newton_residual),
            contact_residual=float(report.contact_residual), min_det_f=float(report.min_det_f),
            wall_time_s=float(report.wall_time), phase=phase, pad_slip=pad_slip(report, pad_at),
        )

    def to_dict(self) -> dict:
        """The ``summary.json`` form (angles in degrees)."""
        return {
            "step": self.step, "command": command_to_dict(self.command), "converged": self.converged,
            "status": self.status, "upper_centroid": list(self.upper_centroid),
            "lower_centroid": list(self.lower_centroid), "lower_yaw_deg": self.lower_yaw_deg,
            "lower_direction_deviation_deg": self.lower_direction_deviation_deg,
            "twist_deg": self.lower_direction_deviation_deg, "lag": list(self.lag), "max_slip": self.max_slip,
            "pressure_max": self.pressure_max, "pressure_min": self.pressure_min,
            "normal_force": self.normal_force, "tangential_force": list(self.tangential_force),
            "upper_force": list(self.upper_force), "equilibrium_error": self.equilibrium_error,
            "n_stick": self.n_stick, "n_slip": self.n_slip, "n_separated": self.n_separated,
            "dissipation": self.dissipation, "newton_iterations": self.newton_iterations,
            "contact_iterations": self.contact_iterations, "newton_residual": self.newton_residual,
            "contact_residual": self.contact_residual, "min_det_f": self.min_det_f,
            "wall_time_s": self.wall_time_s, "phase": self.phase, "pad_slip": self.pad_slip,
        }

    @classmethod
    def from_dict(cls, d: dict) -> StepSummary:
        """Inverse of :meth:`to_dict` (a ``summary.json`` step written by this version;
        an older one without ``lower_direction_deviation_deg`` reads ``twist_deg``).  A
        ``null`` deviation (the lower face had not moved) reads back as ``nan``."""
        values = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        tuples = ("upper_centroid", "lower_centroid", "lag", "tangential_force", "upper_force")
        values.update({k: _floats(d[k]) for k in tuples})
        deviation = d.get("lower_direction_deviation_deg", d.get("twist_deg"))
        values.update(command=command_from_dict(d["command"], "command"),
                      lower_yaw=math.radians(d["lower_yaw_deg"]),
                      twist=math.nan if deviation is None else math.radians(deviation))
        return cls(**values)


@dataclass(frozen=True)
class Failure:
    """The step at which a run stopped and why."""

    step: int
    status: str
    message: str

    def to_dict(self) -> dict:
        return {"step": self.step, "status": self.status, "message": self.message}


@dataclass(frozen=True)
class RestSummary:
    """The block at rest after a release (the last release step; SI units, yaw in rad).

    ``status`` is ``"settled"`` or ``"not_settled"`` (:class:`fe_contact.Rest`),
    ``reason`` why not; ``pad_force`` the plate's remaining force, N, and
    ``further_motion`` how far one more step moves a node, m."""

    mode: str
    lower_centroid: tuple[float, float, float]
    lower_yaw: float
    upper_centroid: tuple[float, float, float]
    normal_force: float
    tangential_force: tuple[float, float]
    strain_energy: float
    status: str
    step: int | None = None  # the step at which the block is at rest (the last release step)
    reason: str = ""
    pad_force: float = 0.0
    further_motion: float = 0.0
    gripper_friction: str | dict = "bonded"
    """The pad's friction the rest pose assumes: "bonded" or {mu_x, mu_y, angle_deg}."""
    pad_slip: float | None = None
    """m, how far a frictional pad had slid over the upper face when it let go; None when bonded."""

    @property
    def settled(self) -> bool:
        return self.status == "settled"

    @classmethod
    def from_report(cls, report: StepReport, mode: str, rest: Rest, gripper_friction="bonded",
                    pad_slip: float | None = None) -> RestSummary:
        return cls(mode=mode, step=report.step_index, lower_centroid=_floats(report.lower_centroid),
                   lower_yaw=float(report.lower_yaw),
                   upper_centroid=_floats(report.upper_centroid), normal_force=float(report.normal_force),
                   tangential_force=_floats(report.tangential_force), strain_energy=float(report.strain_energy),
                   status=rest.status, reason=rest.reason, pad_force=rest.pad_force,
                   further_motion=rest.further_motion, gripper_friction=gripper_friction, pad_slip=pad_slip)

    @property
    def lower_yaw_deg(self) -> float:
        return math.degrees(self.lower_yaw)

    def to_dict(self) -> dict:
        return {"mode": self.mode, "lower_centroid": list(self.lower_centroid), "lower_yaw_deg": self.lower_yaw_deg,
                "upper_centroid": list(self.upper_centroid), "normal_force": self.normal_force,
                "tangential_force": list(self.tangential_force), "strain_energy": self.strain_energy,
                "status": self.status, "step": self.step, "reason": self.reason, "pad_force": self.pad_force,
                "further_motion": self.further_motion, "gripper_friction": self.gripper_friction,
                "pad_slip": self.pad_slip}

    @classmethod
    def from_dict(cls, d: dict) -> RestSummary:
        return cls(mode=d["mode"], lower_centroid=_floats(d["lower_centroid"]),
                   lower_yaw=math.radians(d["lower_yaw_deg"]), upper_centroid=_floats(d["upper_centroid"]),
                   normal_force=float(d["normal_force"]), tangential_force=_floats(d["tangential_force"]),
                   strain_energy=float(d["strain_energy"]), status=d["status"], step=d.get("step"),
                   reason=d.get("reason", ""), pad_force=float(d.get("pad_force", 0.0)),
                   further_motion=float(d.get("further_motion", 0.0)),
                   gripper_friction=d.get("gripper_friction", "bonded"), pad_slip=d.get("pad_slip"))


@dataclass
class RunSummary:
    """What ``summary.json`` holds, as typed data."""

    scenario: dict
    steps: list[StepSummary] = field(default_factory=list)
    status: RunStatus = RunStatus.RUNNING
    failure: Failure | None = None
    elapsed_s: float = 0.0
    rest: RestSummary | None = None

    @property
    def completed(self) -> bool:
        return self.status is RunStatus.COMPLETED

    @property
    def warnings(self) -> list[str]:
        """Warnings about what the run's numbers mean (:func:`pad_slip_warning`)."""
        return [w for w in (pad_slip_warning(self.steps),) if w]

    def to_dict(self) -> dict:
        d = {"scenario": self.scenario, "elapsed_s": self.elapsed_s, "status": self.status.value,
             "failure": None if self.failure is None else self.failure.to_dict(),
             "steps": [s.to_dict() for s in self.steps]}
        if self.warnings:
            d["warnings"] = self.warnings
        return d if self.rest is None else {**d, "rest": self.rest.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> RunSummary:
        failure = d.get("failure")
        return cls(scenario=d["scenario"], steps=[StepSummary.from_dict(s) for s in d["steps"]],
                   status=RunStatus(d["status"]), failure=None if failure is None else Failure(**failure),
                   elapsed_s=float(d["elapsed_s"]),
                   rest=RestSummary.from_dict(d["rest"]) if d.get("rest") else None)


def pad_slip(report: StepReport, pad_at) -> float | None:
    """A frictional pad's slip over the upper face after ``report``'s step, m: the in-plane
    distance between the pad's commanded position ``pad_at`` (3,) and the upper face's
    centroid; None for a bonded pad (no pad contacts) or without ``pad_at``."""
    if report.pad_reaction.shape[0] == 0 or pad_at is None:
        return None
    return float(math.hypot(*(np.asarray(pad_at[:2], float) - np.asarray(report.upper_centroid[:2], float))))


def pad_slip_warning(steps) -> str | None:
    """A line when a frictional pad slid more than :data:`PAD_SLIP_WARN` of the commanded
    in-plane travel over the command steps (``steps``: :class:`StepSummary` rows), else None."""
    loaded = [s for s in steps if s.phase == "command" and s.pad_slip is not None]
    if not loaded:
        return None
    last = loaded[-1]
    commanded = math.hypot(sum(s.command.dx for s in loaded), sum(s.command.dy for s in loaded))
    if commanded <= 0 or last.pad_slip <= PAD_SLIP_WARN * commanded:
        return None
    moved = math.hypot(*last.upper_centroid[:2])
    return (f"the pad slid {last.pad_slip * 1e3:.3g} mm over the upper face of the {commanded * 1e3:.3g} mm "
            f"commanded in the plane (the upper face moved {moved * 1e3:.3g} mm): the pad's friction does not drag "
            f"the block; the poses are of a sliding pad, not of a held block")


def _floats(a) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(a, float).ravel())
