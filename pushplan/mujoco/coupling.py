"""Two-way coupling of the FE block into a user's own MuJoCo loop (:class:`CoSimulation`,
made by :func:`attach`); ``pushplan mujoco cosim`` runs the same coupling.

The user's loop calls ``mj_step`` as usual and :meth:`CoSimulation.couple` once per
control period (after that period's ``mj_step`` calls)::

    coupler = attach(model, data, "scenarios/mujoco_arm.toml", gripper="hand")
    for period in range(n):
        for _ in range(steps_per_period):
            data.ctrl[:] = controller(...)
            mujoco.mj_step(model, data)
        coupler.couple()

Each ``couple()`` turns the gripper's motion since the previous one into one
upper-face ``fe_contact.Command``, steps the FE model, and writes back (world frame,
m, N, N m):

* **the block is kinematic**: its free-joint ``qpos`` is the FE lower-face pose
  (centroid displacement and best-fit yaw), its ``qvel`` zero, and its six dofs carry
  the armature :data:`KINEMATIC_ARMATURE` (set once at attachment, with MuJoCo's
  "simple body" shortcut ``dof_simplenum`` / ``body_simple`` off for it, which would
  ignore the armature), so ``mj_step`` leaves it where the FE put it (a force of 1 kN
  moves it by ~1e-20 m in a 0.05 s period);
  ``xfrc_applied[block]`` is zero.  A mocap block is moved through ``mocap_pos/quat``.
* **the gripper body receives the FE reaction**: ``xfrc_applied[gripper body]`` is the
  force the block's upper face applies on the gripper, ``-F_g``, and its moment about
  the gripper body's centre of mass (where MuJoCo applies ``xfrc_applied``).  The moment of the upper-face forces follows from
  the block's balance (contact + weight + gripper = 0, eq. 3 of the paper).  A
  ``<force>`` / ``<torque>`` sensor on a site of a massless, jointless hand body then
  reads, in the site frame, the wrench the arm applies on the hand, ``F_g`` and its
  moment about the site (``gripper_moment`` when the site is the gripper frame): what
  a wrist force/torque sensor reads.
* ``data.userdata`` (as far as ``<size nuserdata=...>`` holds whole fields), layout
  :data:`USERDATA_LAYOUT`.

MuJoCo's own ``data.contact`` rows for the block are those of a rigid box held still
(their forces are not the FE's); the FE contact resultant is in ``userdata``.  Keep
gripper-block collisions off (``contype``/``conaffinity`` or ``<exclude>``): the FE
carries that interaction.

With ``stiffness=True`` the reaction on an actuated gripper is not held constant
through the period but linearised with the block's condensed stiffness at the
gripper, applied at every ``mj_step`` (:mod:`.stiffness`, which states both modes'
stability conditions); ``couple()`` warns (:class:`~.stiffness.CouplingWarning`)
when a condition fails or the gripper force oscillates period to period.
"""

from __future__ import annotations

import math
import time

import numpy as np

from fe_contact import Command, Model, State, StepReport, initial_state, rollout_derivatives, wrap_angle

from ..errors import InputError
from ..run.driver import drive
from .frames import matrix_yaw, rz
from .mjmodel import find_object, frame_of, mujoco_module
from .scene import MjcfScene
from .stiffness import OMEGA_DT_MAX, LinearisedReaction, omega_dt, oscillates, warn

USERDATA_LAYOUT = {
    "gripper_force": slice(0, 3), "contact_force": slice(3, 6), "contact_moment": slice(6, 9),
    "gripper_moment": slice(9, 12), "contact_counts": slice(12, 15), "period": slice(15, 16),
    "converged": slice(16, 17),
}
"""Where :class:`CoSimulation` writes in ``data.userdata`` (world frame, N, N m):
``gripper_force`` the force the gripper applies on the block's upper face;
``contact_force`` the floor's FE contact resultant on the block and ``contact_moment``
its moment about the block's centre of mass; ``gripper_moment`` the moment of the
gripper's forces on the block about the gripper frame (the origin of the ``gripper``
body or site);
``contact_counts`` the (stick, slip, separated) contact node counts; ``period`` the
number of ``couple()`` calls; ``converged`` 1.0 when the last FE step converged."""
USERDATA_SIZE = 17
KINEMATIC_ARMATURE = 1e20
"""Armature (kg, kg m^2) on the block's free-joint dofs: ``mj_step`` cannot move it."""


class CoSimulation:
    """The FE block coupled into ``mj_model`` / ``mj_data`` (module docstring).

    At construction the block is put at its reference (``qpos0``) pose, made kinematic,
    and the FE state is the undeformed block; the gripper's pose then fixes where the
    upper face is attached to it.  A failed FE step keeps the last good state and pose;
    the next period retries with the accumulated gripper motion.

    Parameters
    ----------
    mj_model, mj_data : mujoco.MjModel, mujoco.MjData
    scene : MjcfScene
        Import of the same MJCF.
    gripper : str
        Body or site carrying the upper face (mocap, or a link of an actuated arm).
    control_period : float
        s of MuJoCo time between FE steps for :meth:`update`; :meth:`couple` ignores it.
    fe_model : fe_contact.Model, optional
        Defaults to ``scene.scenario.model()``; its block must have the MJCF size.
    stiffness : bool
        Linearise the reaction within each period with the block's condensed stiffness
        at the gripper (:mod:`.stiffness`; each period's FE step is then differentiated,
        about 1.3x its cost, and MuJoCo's passive-force callback is taken until :meth:`close`).

    Raises
    ------
    InputError
        ``control_period`` below the MuJoCo timestep, ``fe_model`` of another size, a
        block without a free joint or mocap, an unknown gripper, a gripper geom that
        collides with the block.
    """

    def __init__(self, mj_model, mj_data, scene: MjcfScene, gripper: str = "gripper",
                 control_period: float = 0.05, fe_model: Model | None = None, stiffness: bool = False):
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
        self._gbody = self._gid if self._gkind == "body" else int(mj_model.site_bodyid[self._gid])
        _check_no_collision(mj_model, self._gbody, find_object(
            mj_model, mj.mjtObj.mjOBJ_GEOM, scene.block_geom, "block geom"), gripper)
        yaw_g = matrix_yaw(Rg)
        self._offset = rz(-yaw_g) @ (scene.upper_centre - pg)
        self._last = (scene.upper_centre.copy(), yaw_g)
        self._next = mj_data.time + self.control_period
        self.lower_displacement = np.zeros(3)  # FE frame, m
        self.lower_yaw = 0.0
        self.gripper_force = np.zeros(3)  # world, N: gripper on the block's upper face
        self.gripper_moment = np.zeros(3)  # world, N m: of the gripper's forces, about the gripper frame
        self._moment_at_com = np.zeros(3)  # the same about the gripper body's CoM (where xfrc acts)
        self.contact_force = np.zeros(3)  # world, N: floor on the block (FE contact resultant)
        self.contact_moment = np.zeros(3)  # world, N m: about the block body's centre of mass
        self.contact_counts = np.zeros(3)  # stick, slip, separated contact nodes
        self.period = 0
        self.converged = 1.0
        self.stiffness = np.zeros((3, 3))  # N/m, world: d F_g / d gripper translation (stiffness=True)
        self.warned: set[str] = set()  # "oscillation", "stability": each warned once
        self._forces: list[np.ndarray] = []
        self._reaction = LinearisedReaction(self) if stiffness else None
        self._write()
        mj.mj_forward(mj_model, mj_data)

    def _attach_block(self, bid: int) -> None:
        """Where the block pose is written (its mocap slot, or its free joint's qpos /
        qvel); a free block's dofs get :data:`KINEMATIC_ARMATURE`."""
        mj, m = mujoco_module(), self.mj_model
        self._bid = bid
        self._mocap = int(m.body_mocapid[bid])
        if self._mocap < 0:
            jnt = int(m.body_jntadr[bid])
            if m.body_jntnum[bid] != 1 or m.jnt_type[jnt] != mj.mjtJoint.mjJNT_FREE:
                raise InputError(f"block body {self.scene.block_body!r} must have one free joint or be a mocap body")
            self._qadr, self._vadr = int(m.jnt_qposadr[jnt]), int(m.jnt_dofadr[jnt])
            m.dof_armature[self._vadr:self._vadr + 6] = KINEMATIC_ARMATURE
            # MuJoCo's "simple body" shortcut inverts a free body's diagonal mass matrix
            # as compiled, without the armature; off, the armature counts
            m.dof_simplenum[self._vadr:self._vadr + 6] = 0
            m.body_simple[bid] = 0

    def drive_pose(self) -> tuple[np.ndarray, float]:
        """(world upper-face centre carried by the gripper (3,), gripper yaw) now."""
        d = self.mj_data
        if self._gkind == "body":
            p, R = d.xpos[self._gid], d.xmat[self._gid].reshape(3, 3)
        else:
            p, R = d.site_xpos[self._gid], d.site_xmat[self._gid].reshape(3, 3)
        yaw = matrix_yaw(R)
        return p + rz(yaw) @ self._offset, yaw

    def gripper_wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """The wrench the arm must supply to hold the block's reaction now (world, N, N m about
        the gripper body's centre of mass): ``F_g`` and its moment, linearised at the
        gripper's pose now with ``stiffness=True`` (:mod:`.stiffness`, eq. (2))."""
        if self._reaction is not None:
            return self._reaction.wrench()
        return self.gripper_force.copy(), self._moment_at_com.copy()

    def _frame_position(self) -> np.ndarray:
        """(3,) world origin of the gripper body or site now."""
        d = self.mj_data
        return (d.xpos if self._gkind == "body" else d.site_xpos)[self._gid].copy()

    def block_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World (pos (3,), quat (4,)) of the block body for the current FE lower-face pose."""
        return self.scene.body_pose(self.lower_displacement, self.lower_yaw)

    def _measure_forces(self, rep: StepReport) -> None:
        """World-frame forces of a converged step: gripper force ``F_g``; contact
        resultant and its moment about the block's CoM; the moment of the gripper's
        forces about the gripper frame origin ``P`` from the balance
        ``M_g(P) = -sum (x_i - P) x f_i`` over the contact and self-weight nodal forces
        ``f_i`` at the deformed nodes ``x_i``, and about the gripper body's CoM ``C``,
        ``M_g(C) = M_g(P) + (P - C) x F_g``, for ``xfrc_applied``."""
        mj, s, d = mujoco_module(), self.scene, self.mj_data
        mesh = self.model.mesh
        nodes = s.lower_centre + s.to_world(mesh.nodes + rep.displacement)
        forces = s.to_world(rep.reaction_world)
        pos, quat = self.block_pose()
        com = np.zeros(3)
        mj.mju_rotVecQuat(com, np.asarray(self.mj_model.body_ipos[self._bid], float), quat)
        self.gripper_force = s.to_world(rep.upper_force)
        self.contact_force = forces.sum(axis=0)
        self.contact_moment = np.cross(nodes[mesh.lower] - (pos + com), forces).sum(axis=0)
        arms, loads = nodes[mesh.lower], forces
        if self.model.body_force is not None:
            arms = np.vstack([arms, nodes])
            loads = np.vstack([loads, s.to_world(self.model.body_force.reshape(-1, 3))])
        frame, com = self._frame_position(), d.xipos[self._gbody]
        self.gripper_moment = -np.cross(arms - frame, loads).sum(axis=0)
        self._moment_at_com = self.gripper_moment + np.cross(frame - com, self.gripper_force)
        self.contact_counts = np.array([rep.n_stick, rep.n_slip, rep.n_separated], float)

    def _write(self) -> None:
        """Block pose (qvel 0) or mocap pose, the gripper's reaction, ``userdata``."""
        pos, quat = self.block_pose()
        d = self.mj_data
        d.xfrc_applied[self._bid] = 0.0
        if self._gbody != 0:  # the world body takes no force; with stiffness the passive callback applies it
            d.xfrc_applied[self._gbody] = 0.0 if self._reaction else -np.concatenate([self.gripper_force,
                                                                                     self._moment_at_com])
        for key, where in USERDATA_LAYOUT.items():
            if where.stop <= self.mj_model.nuserdata:
                d.userdata[where] = getattr(self, key)
        if self._mocap >= 0:
            d.mocap_pos[self._mocap], d.mocap_quat[self._mocap] = pos, quat
        else:
            d.qpos[self._qadr:self._qadr + 3], d.qpos[self._qadr + 3:self._qadr + 7] = pos, quat
            d.qvel[self._vadr:self._vadr + 6] = 0.0

    def update(self) -> StepReport | None:
        """For a loop that calls this after every ``mj_step``: :meth:`couple` when a
        control period is due (returns its report), otherwise None."""
        if self.mj_data.time + 0.5 * self.mj_model.opt.timestep < self._next:
            return None
        self._next += self.control_period
        return self.couple()

    def couple(self) -> StepReport:
        """One control period now: gripper motion -> FE step -> block pose and forces into MuJoCo."""
        mj = mujoco_module()
        t0 = time.perf_counter()
        mj.mj_kinematics(self.mj_model, self.mj_data)
        centre, yaw = self.drive_pose()
        d = self.scene.to_fe(centre - self._last[0])
        rep, state = self._step(Command(d[0], d[1], d[2], wrap_angle(yaw - self._last[1])))
        self.reports.append(rep)
        self.period += 1
        self.converged = float(rep.converged)
        if rep.converged:  # otherwise the next period retries from the last good state
            self.state, self._last = state, (centre, yaw)
            self.lower_displacement = np.array(rep.lower_centroid, float)
            self.lower_yaw = float(rep.lower_yaw)
            self._measure_forces(rep)
            self._check(centre)
        self._write()
        mj.mj_forward(self.mj_model, self.mj_data)
        self.step_wall.append(time.perf_counter() - t0)
        return rep

    control = couple  # the name before issue 33

    def _step(self, command: Command) -> tuple[StepReport, State | None]:
        """The period's FE step (with ``stiffness``: differentiated, :attr:`stiffness` set)."""
        if self._reaction is None:
            run = drive(self.model, [command], self.state)
            return run.reports[-1], run.state
        result = rollout_derivatives(self.model, [command], state=self.state, parameters=())
        if not result.converged or not result.reports:
            run = drive(self.model, [command], self.state)  # the failed step's own report
            return run.reports[-1], None
        R = rz(self.scene.yaw)  # FE frame -> world
        stiffness = R @ result.d_commands[0, 3:6, 0, :3] @ R.T
        if np.all(np.isfinite(stiffness)):  # NaN: a contact at a transition (first touch), no derivative
            self.stiffness = stiffness  # there: the last period's stiffness stands (zero before any)
        return result.reports[-1], result.state

    def _check(self, centre: np.ndarray) -> None:
        """Hand the reaction to the passive callback; warn once on a failed stability
        condition or an oscillating gripper force (:mod:`.stiffness`)."""
        self._forces = [*self._forces[-3:], self.gripper_force.copy()]
        if oscillates(self._forces) and "oscillation" not in self.warned:
            self.warned.add("oscillation")
            warn(f"period {self.period}: the gripper force alternates period to period "
                 f"({', '.join(f'{np.linalg.norm(f):.4g}' for f in self._forces)} N): the coupling is unstable ("
                 + ("check omega * dt" if self._reaction else "without stiffness=True it needs the block's stiffness "
                    "at the gripper below the arm's") + "; docs/mujoco-coupling.md)")
        if self._reaction is None or self._gbody == 0:
            return
        self._reaction.set(self.gripper_force, self._moment_at_com, centre, self.stiffness)
        w = omega_dt(self.mj_model, self.mj_data, self._gbody, self.stiffness)
        if w >= OMEGA_DT_MAX and "stability" not in self.warned:
            self.warned.add("stability")
            warn(f"period {self.period}: the block's stiffness at the gripper gives omega * dt = {w:.3g} >= {OMEGA_DT_MAX:g} with "
                 f"the MuJoCo timestep {self.mj_model.opt.timestep} s: MuJoCo's explicit step of the reaction is "
                 "unstable; lower the timestep (docs/mujoco-coupling.md)")

    def close(self) -> None:
        """Give MuJoCo's passive-force callback back (``stiffness=True``); idempotent."""
        if self._reaction is not None:
            self._reaction.close()
            self._reaction = None


def _collides(m, g1: int, g2: int) -> bool:
    """Whether MuJoCo may generate a contact between geoms ``g1`` and ``g2``: an explicit
    ``<pair>``, or compatible ``contype``/``conaffinity`` bits on bodies not excluded."""
    pairs = {tuple(sorted(p)) for p in zip(m.pair_geom1, m.pair_geom2, strict=True)}
    if tuple(sorted((g1, g2))) in pairs:
        return True
    if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
        return False
    b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
    signature = (min(b1, b2) << 16) + max(b1, b2)
    return signature not in set(int(s) for s in m.exclude_signature)


def _check_no_collision(m, gbody: int, bgeom: int, gripper: str) -> None:
    """Refuse a gripper body whose geoms collide with the block: the FE carries that
    contact, MuJoCo would count it twice."""
    mj = mujoco_module()
    for g in np.flatnonzero(m.geom_bodyid == gbody):
        if _collides(m, int(g), bgeom):
            name = mj.mj_id2name(m, mj.mjtObj.mjOBJ_GEOM, int(g)) or f"geom {int(g)}"
            raise InputError(f"gripper {gripper!r}: its geom {name!r} collides with the block geom; set its "
                             "contype and conaffinity to 0 (the FE model carries the gripper-block contact)")


def attach(mj_model, mj_data, scene, gripper: str = "gripper", fe_model: Model | None = None,
           control_period: float | None = None, stiffness: bool = False) -> CoSimulation:
    """The FE block coupled into the user's ``mj_model`` / ``mj_data``.

    ``scene`` is an :class:`MjcfScene`, or a path to a scenario TOML with a ``[mujoco]``
    table / an MJCF file (:func:`~pushplan.mujoco.scene.open_scene`); it must describe
    the same scene as ``mj_model``.  ``control_period`` (s, for :meth:`CoSimulation.update`)
    defaults to the scenario's ``mujoco.control_period``.  Call ``couple()`` on the
    result once per control period (module docstring).  ``stiffness``: linearise the
    reaction within the period (:class:`CoSimulation`, :mod:`.stiffness`).
    """
    from .scene import open_scene

    settings = None
    if not isinstance(scene, MjcfScene):
        scene, settings = open_scene(scene)
    period = control_period if control_period is not None else (settings.control_period if settings else 0.05)
    return CoSimulation(mj_model, mj_data, scene, gripper, period, fe_model, stiffness)
