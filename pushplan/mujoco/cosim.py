"""Headless co-simulation: the coupling of :mod:`.coupling` (the same one a user's own
loop calls) along a command list with a mocap gripper (:func:`run_cosimulation`), its
record (:class:`CosimRecord`) and rerun recording (:func:`save_recording`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from fe_contact import Command, Model, StepReport, warm_up

from ..config.commands import command_to_dict
from ..errors import InputError
from ..run.summary import RunStatus, StepSummary
from .coupling import CoSimulation
from .mjmodel import check_mujoco_work, geom_label, mocap_index, mujoco_module
from .scene import MjcfScene, block_geom_pose
from .trajectory import gripper_trajectory


@dataclass(frozen=True)
class CosimPeriod:
    """One control period of :func:`run_cosimulation`, MuJoCo world frame (m, rad, N).

    ``gripper_centre`` (3,) upper-face centre carried by the gripper at the period's
    end; ``lower_centre`` (3,) and ``lower_yaw`` the FE lower-face pose (centre and
    yaw); ``mujoco_lower_centre`` (3,) and ``mujoco_yaw`` the block pose MuJoCo shows;
    ``gripper_force``, ``contact_force``, ``contact_moment`` (3,) what the coupler wrote
    into MuJoCo (see :mod:`.coupling`); ``boxes`` name -> (centre (3,), quat (4,),
    half sizes (3,)) of every MuJoCo box geom (the recording draws them)."""

    period: int
    time: float
    report: StepReport
    gripper_centre: np.ndarray
    lower_centre: np.ndarray
    lower_yaw: float
    mujoco_lower_centre: np.ndarray
    mujoco_yaw: float
    gripper_force: np.ndarray
    contact_force: np.ndarray
    contact_moment: np.ndarray
    boxes: dict
    control_wall_s: float

    def to_dict(self) -> dict:
        """World-frame poses and forces; the FE-frame command and pose under ``fe_frame``;
        ``lower_direction_deviation_deg`` as in ``summary.json`` (null while the lower face sticks)."""
        rep = self.report
        deviation = StepSummary.from_report(rep).lower_direction_deviation_deg if rep.converged else None
        return {
            "period": self.period, "time": self.time, "status": rep.status.value,
            "gripper_centre": self.gripper_centre, "lower_centre": self.lower_centre,
            "lower_yaw_deg": math.degrees(self.lower_yaw), "lower_direction_deviation_deg": deviation,
            "twist_deg": deviation,  # the name before issue 33, kept one release
            "mujoco_lower_centre": self.mujoco_lower_centre, "mujoco_yaw_deg": math.degrees(self.mujoco_yaw),
            "gripper_force": self.gripper_force, "contact_force": self.contact_force,
            "contact_moment": self.contact_moment,
            "fe_frame": {"command": command_to_dict(rep.command), "lower_centroid": rep.lower_centroid,
                         "lower_yaw_deg": math.degrees(rep.lower_yaw)},
            "fe_step_s": rep.wall_time, "control_wall_s": self.control_wall_s,
        }


def _boxes(m, d) -> dict:
    """name -> (centre (3,), quat (4,), half sizes (3,)) of every box geom of ``m`` in ``d``."""
    mj = mujoco_module()
    out = {}
    for g in np.flatnonzero(m.geom_type == mj.mjtGeom.mjGEOM_BOX):
        quat = np.zeros(4)
        mj.mju_mat2Quat(quat, d.geom_xmat[g])
        out[geom_label(m, int(g))] = (d.geom_xpos[g].copy(), quat, m.geom_size[g].copy())
    return out


@dataclass(frozen=True)
class CosimRecord:
    """A headless co-simulation: settings, FE mesh, the periods run, the wall time of the
    control loop and, before it, the start-up (loading the compiled kernels)."""

    scene: MjcfScene
    gripper: str
    control_period: float
    steps_per_period: int
    fe_model: Model
    n_commands: int
    periods: tuple[CosimPeriod, ...]
    wall_s: float
    startup_s: float = 0.0

    @property
    def status(self) -> RunStatus:
        """Completed when every command ran and the last FE step converged."""
        done = bool(self.periods) and self.periods[-1].report.converged and len(self.periods) == self.n_commands
        return RunStatus.COMPLETED if done else RunStatus.FAILED

    @property
    def rate_periods_per_s(self) -> float:
        return len(self.periods) / self.wall_s if self.wall_s > 0 else math.inf

    def to_dict(self) -> dict:
        """The ``cosim.json`` form."""
        return {
            "scene": self.scene.to_dict(), "gripper": self.gripper, "control_period": self.control_period,
            "mujoco_steps_per_period": self.steps_per_period, "fe_elements": list(self.fe_model.mesh.divisions),
            "fe_quadrature": self.fe_model.quadrature, "status": self.status.value,
            "periods": [p.to_dict() for p in self.periods], "wall_s": self.wall_s, "startup_s": self.startup_s,
            "rate_periods_per_s": self.rate_periods_per_s,
        }


def run_cosimulation(scene: MjcfScene, commands: Sequence[Command], gripper: str = "gripper",
                     control_period: float = 0.05, fe_model: Model | None = None, rrd_path=None) -> CosimRecord:
    """Headless co-simulation: the gripper mocap follows ``commands`` (one per
    control period, linear in between), the coupler steps the FE model; it stops at
    the first period whose FE step failed.  With ``rrd_path`` the run is also saved
    as a rerun recording.

    Raises
    ------
    InputError
        Scene not from a file, ``control_period`` not a multiple of the MuJoCo timestep,
        bad gripper or commands.
    """
    mj = mujoco_module()
    m = scene.mj_model("run_cosimulation")
    traj = gripper_trajectory(scene, m, commands, gripper, control_period)
    check_mujoco_work(len(commands), control_period, m.opt.timestep)
    n_sub = int(round(control_period / m.opt.timestep))
    if n_sub < 1 or abs(n_sub * m.opt.timestep - control_period) > 1e-9 * control_period:
        raise InputError(f"control_period {control_period} must be a multiple of the MuJoCo timestep {m.opt.timestep}")
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    coupler = CoSimulation(m, d, scene, gripper, control_period, fe_model)
    mocap = mocap_index(m, gripper)
    periods = []
    startup = warm_up()  # the compiled kernels, loaded before the loop as a controller would
    t0 = time.perf_counter()
    fractions = np.arange(1, n_sub + 1) / n_sub
    for k in range(len(commands)):
        for pos, quat in zip(*traj.between(k, fractions), strict=True):
            d.mocap_pos[mocap], d.mocap_quat[mocap] = pos, quat
            mj.mj_step(m, d)
        rep = coupler.couple()
        low, _, yaw = block_geom_pose(m, d, scene)
        periods.append(CosimPeriod(
            k + 1, float(d.time), rep, traj.upper_centre[k + 1],
            scene.lower_centre + scene.to_world(coupler.lower_displacement), scene.yaw + coupler.lower_yaw,
            low, yaw, coupler.gripper_force.copy(), coupler.contact_force.copy(), coupler.contact_moment.copy(),
            _boxes(m, d), coupler.step_wall[-1]))
        if not rep.converged:
            break
    record = CosimRecord(scene, gripper, control_period, n_sub, coupler.model, len(commands), tuple(periods),
                         time.perf_counter() - t0, startup)
    if rrd_path is not None:
        save_recording(Path(rrd_path), record)
    return record


def save_recording(path: Path, record: CosimRecord) -> None:
    """Rerun recording of a co-simulation, in the MuJoCo world frame.

    The FE steps go through :class:`pushplan.outputs.recording.Recorder` (replayable;
    its ``world/...`` entities are in the FE frame, placed in the MuJoCo world by a static
    ``Transform3D`` on ``world``).  ``world/mujoco`` undoes that transform, so its
    children are in MuJoCo world coordinates: per period ``world/mujoco/<geom>`` draws
    every MuJoCo box geom (``Boxes3D``), ``world/mujoco/gripper_centre`` the
    gripper-carried upper-face centre, ``world/mujoco/fe_forces`` the FE contact
    resultant and gripper force written into MuJoCo (``Arrows3D``, the largest of the run
    as long as the block is high);
    ``plots/mujoco_yaw_deg`` is the block yaw MuJoCo shows.  Timelines: the
    recorder's ``step`` and ``load``, and ``sim_time`` (s of MuJoCo time, a duration).
    """
    import rerun as rr

    from ..outputs.recording import Recorder

    scene = record.scene
    with Recorder(path, f"cosim_{scene.scenario.name}", record.fe_model.mesh,
                  scenario=scene.scenario.to_dict()) as rec:
        log = rec.stream.log
        rec.stream.set_time("sim_time", duration=0.0)
        place = {"translation": scene.lower_centre,
                 "rotation": rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=scene.yaw)}
        log("world", rr.Transform3D(**place), static=True)
        log("world/mujoco", rr.Transform3D(**place, relation=rr.TransformRelation.ChildFromParent), static=True)
        largest = max((np.linalg.norm(f) for p in record.periods for f in (p.contact_force, p.gripper_force)),
                      default=0.0)
        arrow = scene.scenario.size[2] / largest if largest > 0 else 0.0  # m per N
        for p in record.periods:
            rec.stream.set_time("sim_time", duration=p.time)
            rep = p.report
            rec.log_step(rep, StepSummary.from_report(rep) if rep.converged else None)
            for name, (centre, quat, half) in p.boxes.items():
                log(f"world/mujoco/{name}", rr.Boxes3D(centers=[centre], half_sizes=[half],
                                                 quaternions=[rr.Quaternion(xyzw=np.roll(quat, -1))]))
            log("world/mujoco/gripper_centre", rr.Points3D([p.gripper_centre]))
            log("world/mujoco/fe_forces", rr.Arrows3D(
                origins=[p.lower_centre, p.gripper_centre],
                vectors=arrow * np.array([p.contact_force, p.gripper_force]),
                labels=["FE contact resultant", "FE gripper force"]))
            log("plots/mujoco_yaw_deg", rr.Scalars(math.degrees(p.mujoco_yaw)))
