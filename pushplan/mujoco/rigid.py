"""The MuJoCo rigid box of the comparison, with the MJCF ``<pair>`` friction: welded
to the mocap gripper (:func:`rigid_weld_run`) or pushed by a force at its centre of
mass (:func:`rigid_force_run`).

``MjSpec.add_equality`` starts with the *connect* data layout; a weld needs its data
set explicitly (anchor 0, relpose "from qpos0" sentinel, torquescale 1).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fe_contact import ZERO_MOTION, Command, wrap_angle

from .mjmodel import find_object, mocap_index, mujoco_module
from .records import ComparisonStep
from .scene import MjcfScene, block_geom_pose
from .trajectory import GripperTrajectory

WELD_TIMECONST_STEPS = 2.0
"""Weld ``solref`` time constant in timesteps (MuJoCo's stable minimum is 2)."""
FORCE_RUN_MAX_PERIODS = 50
"""Force-driven rigid box: time limit per command, in control periods."""


def _weld_model(scene: MjcfScene, gripper: str):
    """The scene's ``MjModel`` with the block body welded to ``gripper`` at their qpos0 pose."""
    mj = mujoco_module()
    spec = mj.MjSpec.from_file(scene.source)
    eq = spec.add_equality()
    eq.name, eq.type, eq.objtype = "pushplan_weld", mj.mjtEq.mjEQ_WELD, mj.mjtObj.mjOBJ_BODY
    eq.name1, eq.name2 = gripper, scene.block_body
    data = np.zeros(len(eq.data))
    data[3:10] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # relpose sentinel: keep the qpos0 relative pose
    data[10] = 1.0  # torquescale
    eq.data = data
    eq.solref = [WELD_TIMECONST_STEPS * spec.option.timestep, 1.0]
    return spec.compile()


def rigid_weld_run(scene: MjcfScene, traj: GripperTrajectory, n_move: int, n_settle: int) -> tuple[ComparisonStep, ...]:
    """Rigid box welded to the gripper, which follows ``traj`` in ``n_move`` MuJoCo
    steps per command and holds for ``n_settle``."""
    mj = mujoco_module()
    m = _weld_model(scene, traj.gripper)
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    mocap = mocap_index(m, traj.gripper)
    low0, up0, yaw0 = block_geom_pose(m, d, scene)
    out, scale = [], max(scene.scenario.size)
    fractions = np.minimum(np.arange(1, n_move + n_settle + 1) / n_move, 1.0)
    for k in range(traj.time.size - 1):
        for pos, quat in zip(*traj.between(k, fractions), strict=True):
            d.mocap_pos[mocap], d.mocap_quat[mocap] = pos, quat
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        low, up, yaw = block_geom_pose(m, d, scene)
        out.append(ComparisonStep.measure(k + 1, traj.upper_centre[k + 1] - traj.upper_centre[0], up - up0,
                                          low - low0, wrap_angle(yaw - yaw0), scale))
    return tuple(out)


def _push_force(scene: MjcfScene, c: Command, weight: float, force_factor: float) -> np.ndarray:
    """World force (3,) N along the in-plane direction of ``c``: ``force_factor`` times the
    elliptic sliding threshold ``W / |M^-1 u|`` (``u`` in the friction axes, ``M =
    diag(mu_x, mu_y)``), at least ``1e-3 W``."""
    s = scene.scenario
    a = math.radians(s.angle_deg)
    u = np.array([c.dx, c.dy]) / math.hypot(c.dx, c.dy)
    u_fr = np.array([math.cos(a) * u[0] + math.sin(a) * u[1], -math.sin(a) * u[0] + math.cos(a) * u[1]])
    mu = np.array([s.mu_x, s.mu_y])
    threshold = weight / np.linalg.norm(u_fr / mu) if np.all(mu > 0) else weight * float(np.min(mu))
    return max(threshold, 1e-3 * weight) * force_factor * scene.to_world(np.array([u[0], u[1], 0.0]))


def rigid_force_run(scene: MjcfScene, commands: Sequence[Command], traj: GripperTrajectory, n_move: int,
                    n_settle: int, force_factor: float) -> tuple[ComparisonStep, ...]:
    """Rigid box pushed by a horizontal force at its centre of mass: per command, a
    constant force along the command direction, ``force_factor`` times the sliding
    threshold under the box's weight, until the box has travelled the command's
    in-plane length (at most ``FORCE_RUN_MAX_PERIODS * n_move`` steps); then released
    and settled for ``n_settle`` steps.  Vertical moves are not applied."""
    mj = mujoco_module()
    m = scene.mj_model("rigid_force_run")
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    bid = find_object(m, mj.mjtObj.mjOBJ_BODY, scene.block_body, "block body")
    for _ in range(n_settle):
        mj.mj_step(m, d)
    low0, up0, yaw0 = block_geom_pose(m, d, scene)
    weight = scene.block_mass * float(np.linalg.norm(m.opt.gravity))
    out, scale = [], max(scene.scenario.size)
    for k, c in enumerate(commands, start=1):
        length = math.hypot(c.dx, c.dy)
        if length > ZERO_MOTION * scale:
            force = _push_force(scene, c, weight, force_factor)
            start = block_geom_pose(m, d, scene)[0]
            for _ in range(FORCE_RUN_MAX_PERIODS * n_move):
                d.xfrc_applied[bid, :3] = force
                mj.mj_step(m, d)
                if np.linalg.norm((d.xpos[bid] - start)[:2]) >= length:
                    break
            d.xfrc_applied[bid, :3] = 0.0
        for _ in range(n_settle):
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        low, up, yaw = block_geom_pose(m, d, scene)
        drive = traj.upper_centre[k] - traj.upper_centre[0]
        out.append(ComparisonStep.measure(k, drive, up - up0, low - low0, wrap_angle(yaw - yaw0), scale))
    return tuple(out)
