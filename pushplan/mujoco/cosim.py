"""Co-simulation: the FE block inside an ordinary MuJoCo stepping loop
(:class:`CoSimulation`), and a headless run of it along a command list
(:func:`run_cosimulation`) with its record and rerun recording.

Each control period the gripper's motion becomes one upper-face
``fe_contact.Command``, run through :func:`pushplan.run.drive`; the FE lower-face pose
(centroid displacement and best-fit yaw) is written into the MuJoCo block, and the FE
forces where a MuJoCo controller reads them (world frame, N and N m):

* ``data.xfrc_applied[block]``: the FE contact resultant the floor applies on the
  block (``[0:3]``) and its moment about the block body's centre of mass (``[3:6]``);
* ``data.userdata[0:9]`` (when the MJCF has ``<size nuserdata="9"/>`` or more), the
  layout :data:`USERDATA_LAYOUT`: the force the gripper applies on the block's upper
  face, the contact resultant and its moment about the centre of mass.

MuJoCo's own ``data.contact`` forces on the block remain those of its rigid box.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from fe_contact import Command, Model, State, StepReport, initial_state, warm_up
from fe_contact.stepping.pose import wrap_angle

from ..config.commands import command_to_dict
from ..errors import InputError
from ..run.driver import drive
from ..run.summary import RunStatus, StepSummary
from .frames import matrix_yaw, rz
from .mjmodel import find_object, frame_of, mocap_index, mujoco_module, object_name
from .scene import MjcfScene, block_geom_pose
from .trajectory import gripper_trajectory


USERDATA_LAYOUT = {"gripper_force": slice(0, 3), "contact_force": slice(3, 6), "contact_moment": slice(6, 9)}
"""Where :class:`CoSimulation` writes the FE forces in ``data.userdata`` (world frame, N, N m)."""
USERDATA_SIZE = 9


class CoSimulation:
    """Couple the FE block into an ordinary MuJoCo stepping loop.

    Call :meth:`update` after every ``mj_step``.  At each control period it turns
    the gripper's displacement since the previous period into an upper-face
    :class:`fe_contact.Command`, steps the FE model and writes the block's
    resulting lower-face pose (centroid displacement and best-fit yaw) into the
    MuJoCo block (free joint ``qpos`` with zero ``qvel``, or mocap pose) and the FE
    forces into ``data.xfrc_applied`` / ``data.userdata`` (module docstring; also kept
    as :attr:`gripper_force`, :attr:`contact_force`, :attr:`contact_moment`, world
    frame).  Between periods it re-writes pose and forces, so MuJoCo shows the FE
    prediction, not its own rigid dynamics.  A failed FE step keeps the last good state and pose; the next
    period retries with the accumulated gripper motion.

    At construction the block is put at its reference (``qpos0``) pose and the FE
    state is the undeformed block; the gripper's pose then fixes where the upper
    face is attached to it.

    Parameters
    ----------
    mj_model, mj_data : mujoco.MjModel, mujoco.MjData
    scene : MjcfScene
        Import of the same MJCF.
    gripper : str
        Body or site carrying the upper face (mocap or any other).
    control_period : float
        s of MuJoCo time between FE steps; the first is one period after construction.
    fe_model : fe_contact.Model, optional
        Defaults to ``scene.scenario.model()``; its block must have the MJCF size.

    Raises
    ------
    InputError
        ``control_period`` below the MuJoCo timestep, ``fe_model`` of another size, a
        block without a free joint or mocap, an unknown gripper.
    """

    def __init__(self, mj_model, mj_data, scene: MjcfScene, gripper: str = "gripper",
                 control_period: float = 0.05, fe_model: Model | None = None):
        mj = mujoco_module()
        if not (isinstance(control_period, (int, float)) and math.isfinite(control_period)
                and control_period >= mj_model.opt.timestep):
            raise InputError(
                f"control_period must be >= the MuJoCo timestep {mj_model.opt.timestep}, got {control_period!r}")
        self.mj_model, self.mj_data, self.scene = mj_model, mj_data, scene
        self.model = fe_model or scene.scenario.model()
        extent = np.ptp(self.model.mesh.nodes, axis=0)
        if not np.allclose(extent, scene.scenario.size, rtol=1e-9):
            raise InputError(
                f"fe_model block size {extent.tolist()} differs from the MJCF box {list(scene.scenario.size)}")
        self.state: State = initial_state(self.model)
        self.reports: list[StepReport] = []
        self.control_period = float(control_period)
        self.step_wall: list[float] = []
        self._attach_block(find_object(mj_model, mj.mjtObj.mjOBJ_BODY, scene.block_body, "block body"))
        mj.mj_kinematics(mj_model, mj_data)
        self._gkind, self._gid, pg, Rg = frame_of(mj_model, mj_data, gripper)
        yaw_g = matrix_yaw(Rg)
        self._offset = rz(-yaw_g) @ (scene.upper_centre - pg)
        self._last = (scene.upper_centre.copy(), yaw_g)
        self._next = mj_data.time + self.control_period
        self.lower_displacement = np.zeros(3)  # FE frame, m
        self.lower_yaw = 0.0
        self.gripper_force = np.zeros(3)  # world, N: gripper on the block's upper face
        self.contact_force = np.zeros(3)  # world, N: floor on the block (FE contact resultant)
        self.contact_moment = np.zeros(3)  # world, N m: about the block body's centre of mass
        self._write_pose()
        mj.mj_forward(mj_model, mj_data)

    def _attach_block(self, bid: int) -> None:
        """Where the block pose is written: its mocap slot, or its free joint's qpos / qvel."""
        mj, m = mujoco_module(), self.mj_model
        self._bid = bid
        self._mocap = int(m.body_mocapid[bid])
        if self._mocap < 0:
            jnt = int(m.body_jntadr[bid])
            if m.body_jntnum[bid] != 1 or m.jnt_type[jnt] != mj.mjtJoint.mjJNT_FREE:
                raise InputError(f"block body {self.scene.block_body!r} must have one free joint or be a mocap body")
            self._qadr, self._vadr = int(m.jnt_qposadr[jnt]), int(m.jnt_dofadr[jnt])

    def drive_pose(self) -> tuple[np.ndarray, float]:
        """(world upper-face centre carried by the gripper (3,), gripper yaw) now."""
        d = self.mj_data
        if self._gkind == "body":
            p, R = d.xpos[self._gid], d.xmat[self._gid].reshape(3, 3)
        else:
            p, R = d.site_xpos[self._gid], d.site_xmat[self._gid].reshape(3, 3)
        yaw = matrix_yaw(R)
        return p + rz(yaw) @ self._offset, yaw

    def block_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World (pos (3,), quat (4,)) of the block body for the current FE lower-face pose."""
        return self.scene.body_pose(self.lower_displacement, self.lower_yaw)

    def _measure_forces(self, rep: StepReport) -> None:
        """The FE gripper force, contact resultant and its moment about the block's
        centre of mass, world frame, from a converged step."""
        mj, s = mujoco_module(), self.scene
        mesh = self.model.mesh
        points = s.lower_centre + s.to_world(mesh.nodes[mesh.lower] + rep.displacement[mesh.lower])
        forces = s.to_world(rep.reaction_world)
        pos, quat = self.block_pose()
        com = np.zeros(3)
        mj.mju_rotVecQuat(com, np.asarray(self.mj_model.body_ipos[self._bid], float), quat)
        self.gripper_force = s.to_world(rep.upper_force)
        self.contact_force = forces.sum(axis=0)
        self.contact_moment = np.cross(points - (pos + com), forces).sum(axis=0)

    def _write_pose(self) -> None:
        pos, quat = self.block_pose()
        d = self.mj_data
        d.xfrc_applied[self._bid] = np.concatenate([self.contact_force, self.contact_moment])
        if self.mj_model.nuserdata >= USERDATA_SIZE:
            for key, where in USERDATA_LAYOUT.items():
                d.userdata[where] = getattr(self, key)
        if self._mocap >= 0:
            d.mocap_pos[self._mocap], d.mocap_quat[self._mocap] = pos, quat
        else:
            d.qpos[self._qadr:self._qadr + 3], d.qpos[self._qadr + 3:self._qadr + 7] = pos, quat
            d.qvel[self._vadr:self._vadr + 6] = 0.0

    def update(self) -> StepReport | None:
        """Call after each ``mj_step``: runs :meth:`control` when a period is due
        (returns its report), otherwise holds the block pose (returns None)."""
        if self.mj_data.time + 0.5 * self.mj_model.opt.timestep < self._next:
            self._write_pose()
            return None
        return self.control()

    def control(self) -> StepReport:
        """One control period now: gripper motion -> FE step -> block pose into MuJoCo."""
        mj = mujoco_module()
        t0 = time.perf_counter()
        mj.mj_kinematics(self.mj_model, self.mj_data)
        centre, yaw = self.drive_pose()
        d = self.scene.to_fe(centre - self._last[0])
        run = drive(self.model, [Command(d[0], d[1], d[2], wrap_angle(yaw - self._last[1]))], self.state)
        rep = run.reports[-1]
        self.reports.append(rep)
        if rep.converged:  # otherwise the next period retries from the last good state
            self.state, self._last = run.state, (centre, yaw)
            self.lower_displacement = np.array(rep.lower_centroid, float)
            self.lower_yaw = float(rep.lower_yaw)
            self._measure_forces(rep)
        self._next += self.control_period
        self._write_pose()
        mj.mj_forward(self.mj_model, self.mj_data)
        self.step_wall.append(time.perf_counter() - t0)
        return rep


@dataclass(frozen=True)
class CosimPeriod:
    """One control period of :func:`run_cosimulation`, MuJoCo world frame (m, rad, N).

    ``gripper_centre`` (3,) upper-face centre carried by the gripper at the period's
    end; ``lower_centre`` (3,) and ``lower_yaw`` the FE lower-face pose (centre and
    yaw); ``mujoco_lower_centre`` (3,) and ``mujoco_yaw`` the block pose MuJoCo shows;
    ``gripper_force``, ``contact_force``, ``contact_moment`` (3,) what the coupler wrote
    into MuJoCo (see the module docstring); ``boxes`` name -> (centre (3,), quat (4,),
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
        """World-frame poses and forces; the FE-frame command and pose under ``fe_frame``."""
        rep = self.report
        return {
            "period": self.period, "time": self.time, "status": rep.status.value,
            "gripper_centre": self.gripper_centre, "lower_centre": self.lower_centre,
            "lower_yaw_deg": math.degrees(self.lower_yaw), "twist_deg": math.degrees(rep.twist),
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
        out[object_name(m, mj.mjtObj.mjOBJ_GEOM, int(g))] = (d.geom_xpos[g].copy(), quat, m.geom_size[g].copy())
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
    for k in range(len(commands)):
        rep = None
        for j in range(1, n_sub + 1):
            d.mocap_pos[mocap], d.mocap_quat[mocap] = traj.at(k, j / n_sub)
            mj.mj_step(m, d)
            rep = coupler.update() or rep
        if rep is None:  # a bug: control_period is a multiple of the timestep
            raise RuntimeError(f"no control step in period {k + 1}")
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
