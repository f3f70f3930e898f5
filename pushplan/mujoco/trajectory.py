"""Gripper trajectories: the mocap knots that carry the block's upper face through a
command list, the FE block pose at each knot, and their export for MuJoCo.

Knot 0 is the reference pose; knot k is reached at the end of command k; all poses
are MuJoCo world frame (m, quaternions w, x, y, z, rad).  ``export_plan`` writes

* ``.npz``: ``time`` (K+1,) s; ``mocap_pos`` (K+1, 3) and ``mocap_quat`` (K+1, 4) of
  the gripper mocap body; ``upper_centre`` (K+1, 3) and ``upper_yaw`` (K+1,) of the
  block's upper-face centre carried by the gripper; ``block_pos`` (K+1, 3) and
  ``block_quat`` (K+1, 4) of the block body and ``lower_centre`` (K+1, 3) /
  ``lower_yaw`` (K+1,) of its lower face, from the FE model driven by the commands;
  ``gripper`` (name).
* ``.csv``: one row per knot, a header line naming the columns :data:`CSV_COLUMNS`
  (the ``.npz`` arrays flattened: ``mocap_pos`` -> ``mocap_x, mocap_y, mocap_z``, ...).
* ``.xml``: an MJCF file with one ``<key>`` per knot: ``mpos`` / ``mquat`` of every
  mocap body (the gripper's from the plan) and ``qpos`` (the model's ``qpos0`` with the
  block's free joint at the FE pose; a mocap block goes into ``mpos`` / ``mquat``), for
  ``<include file="..."/>`` in the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from fe_contact import Command, Model

from ..errors import InputError, SolverFailure
from ..outputs.atomic import atomic_write_bytes, atomic_write_npz
from ..run.driver import drive
from .frames import matrix_yaw, quat_mul, quat_z, rz
from .mjmodel import find_object, mocap_index, mujoco_module
from .scene import MjcfScene

CSV_COLUMNS = (
    "time",
    "mocap_x", "mocap_y", "mocap_z", "mocap_qw", "mocap_qx", "mocap_qy", "mocap_qz",
    "upper_x", "upper_y", "upper_z", "upper_yaw",
    "block_x", "block_y", "block_z", "block_qw", "block_qx", "block_qy", "block_qz",
    "lower_x", "lower_y", "lower_z", "lower_yaw",
)
"""Columns of the ``.csv`` export: s, m, rad, MuJoCo world frame (see the module docstring)."""


@dataclass(frozen=True)
class GripperTrajectory:
    """Gripper knots, one per command boundary (see the module docstring).

    Shapes: ``time`` (K+1,), ``mocap_pos`` (K+1, 3), ``mocap_quat`` (K+1, 4),
    ``upper_centre`` (K+1, 3), ``upper_yaw`` (K+1,)."""

    time: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    upper_centre: np.ndarray
    upper_yaw: np.ndarray
    gripper: str

    def at(self, k: int, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Mocap (pos, quat) a fraction ``s`` in [0, 1] of the way from knot k to k+1."""
        pos, quat = self.between(k, np.array([s], float))
        return pos[0], quat[0]

    def between(self, k: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mocap poses (pos (n, 3), quat (n, 4)) at fractions ``s`` (n,) of the way from
        knot k to k+1: a control period's MuJoCo steps at once (the same numbers as
        :meth:`at` one by one, without its per-step Python work)."""
        s = s[:, None]
        pos = (1 - s) * self.mocap_pos[k] + s * self.mocap_pos[k + 1]
        dyaw = (1 - s[:, 0]) * self.upper_yaw[k] + s[:, 0] * self.upper_yaw[k + 1] - self.upper_yaw[0]
        half = dyaw / 2
        turn = np.zeros((len(half), 4))
        turn[:, 0], turn[:, 3] = np.cos(half), np.sin(half)  # quat_z of each angle
        return pos, quat_mul(turn.T, self.mocap_quat[0]).T


def gripper_trajectory(scene: MjcfScene, mj_model, commands: Sequence[Command], gripper: str = "gripper",
                       control_period: float = 0.05) -> GripperTrajectory:
    """Mocap knots that carry the block's upper face through ``commands``.

    The upper-face centre is rigidly attached to the gripper (yaw only; tilt is not
    representable by the FE command): each command moves it by ``(dx, dy, dz)``
    (FE frame, converted to world) and turns the gripper by ``dtheta``.

    Raises
    ------
    InputError
        ``gripper`` is not a mocap body, bad ``control_period`` or command.
    """
    mj = mujoco_module()
    if not (isinstance(control_period, (int, float)) and math.isfinite(control_period) and control_period > 0):
        raise InputError(f"control_period must be > 0 s, got {control_period!r}")
    mocap_index(mj_model, gripper)
    bid = mj.mj_name2id(mj_model, mj.mjtObj.mjOBJ_BODY, gripper)
    for i, c in enumerate(commands):
        if not isinstance(c, Command):
            raise InputError(f"commands[{i}] must be a fe_contact.Command, got {type(c).__name__}")
    p0 = np.array(mj_model.body_pos[bid], float)
    q0 = np.array(mj_model.body_quat[bid], float)
    R0 = np.zeros(9)
    mj.mju_quat2Mat(R0, q0)
    yaw0 = matrix_yaw(R0.reshape(3, 3))
    offset = rz(-yaw0) @ (scene.upper_centre - p0)
    steps = np.array([[c.dx, c.dy, c.dz] for c in commands], float).reshape(-1, 3)
    turns = np.array([c.dtheta for c in commands], float)
    centre = scene.upper_centre + np.vstack([np.zeros(3), np.cumsum(scene.to_world(steps), axis=0)])
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(turns)])
    pos = centre - np.einsum("kij,j->ki", np.stack([rz(a) for a in yaw]), offset)
    quat = np.stack([quat_mul(quat_z(a - yaw0), q0) for a in yaw])
    times = control_period * np.arange(len(commands) + 1)
    return GripperTrajectory(times, pos, quat, centre, yaw, gripper)


@dataclass(frozen=True)
class BlockKnots:
    """The FE block pose at each knot, world frame: body ``pos`` (K+1, 3), ``quat``
    (K+1, 4), lower-face centre ``lower_centre`` (K+1, 3) m and ``lower_yaw`` (K+1,) rad."""

    pos: np.ndarray
    quat: np.ndarray
    lower_centre: np.ndarray
    lower_yaw: np.ndarray


def block_knots(scene: MjcfScene, fe_model: Model, commands: Sequence[Command]) -> BlockKnots:
    """The block pose at each knot: ``fe_model`` driven by ``commands``, its lower-face
    pose carried into the world by the scene's reference pose.

    Raises
    ------
    SolverFailure
        An FE step did not converge.
    """
    run = drive(fe_model, list(commands))
    if not run.completed:
        raise SolverFailure(f"FE step {len(run.reports)} failed: {run.reports[-1].message}")
    disp = np.vstack([np.zeros(3)] + [np.asarray(r.lower_centroid, float) for r in run.reports])
    yaw = np.concatenate([[0.0], [float(r.lower_yaw) for r in run.reports]])
    poses = [scene.body_pose(u, a) for u, a in zip(disp, yaw, strict=True)]
    return BlockKnots(np.array([p for p, _ in poses]), np.array([q for _, q in poses]),
                      scene.lower_centre + scene.to_world(disp), scene.yaw + yaw)


def keyframes_mjcf(m, traj: GripperTrajectory, scene: MjcfScene, block: BlockKnots) -> str:
    """MJCF text with one ``<key>`` per knot of ``traj``: ``mpos`` / ``mquat`` of every
    mocap body of ``m`` (the gripper's from ``traj``, the others at their model pose) and
    ``qpos`` (``qpos0`` with the block's free joint, or its mocap slot, at ``block``)."""
    mj = mujoco_module()
    mocap_bodies = np.flatnonzero(m.body_mocapid >= 0)
    order = mocap_bodies[np.argsort(m.body_mocapid[mocap_bodies])]
    mine = mocap_index(m, traj.gripper)
    bid = find_object(m, mj.mjtObj.mjOBJ_BODY, scene.block_body, "block body")
    block_mocap, jnt = int(m.body_mocapid[bid]), int(m.body_jntadr[bid])
    free = block_mocap < 0 and m.body_jntnum[bid] == 1 and m.jnt_type[jnt] == mj.mjtJoint.mjJNT_FREE
    fmt = lambda a: " ".join(f"{v:.17g}" for v in a.ravel())  # noqa: E731
    lines = [f'<mujoco model="{traj.gripper}_plan">',
             "  <!-- pushplan plan: gripper mocap and FE block pose per knot; include in the scene -->",
             "  <keyframe>"]
    for k in range(traj.time.size):
        mpos = np.array(m.body_pos[order], float)
        mquat = np.array(m.body_quat[order], float)
        mpos[mine], mquat[mine] = traj.mocap_pos[k], traj.mocap_quat[k]
        qpos = np.array(m.qpos0, float)
        if block_mocap >= 0:
            mpos[block_mocap], mquat[block_mocap] = block.pos[k], block.quat[k]
        elif free:
            a = int(m.jnt_qposadr[jnt])
            qpos[a:a + 3], qpos[a + 3:a + 7] = block.pos[k], block.quat[k]
        qattr = f' qpos="{fmt(qpos)}"' if qpos.size else ""
        lines.append(f'    <key name="plan_{k:03d}" time="{traj.time[k]:.17g}"{qattr} '
                     f'mpos="{fmt(mpos)}" mquat="{fmt(mquat)}"/>')
    lines += ["  </keyframe>", "</mujoco>", ""]
    return "\n".join(lines)


def _csv(traj: GripperTrajectory, block: BlockKnots) -> bytes:
    """The ``.csv`` export: a header of :data:`CSV_COLUMNS`, one row per knot."""
    table = np.column_stack([traj.time, traj.mocap_pos, traj.mocap_quat, traj.upper_centre, traj.upper_yaw,
                             block.pos, block.quat, block.lower_centre, block.lower_yaw])
    rows = [",".join(CSV_COLUMNS)] + [",".join(f"{v:.17g}" for v in row) for row in table]
    return ("\n".join(rows) + "\n").encode()


def export_plan(path, scene: MjcfScene, commands: Sequence[Command], gripper: str = "gripper",
                control_period: float = 0.05, fe_model: Model | None = None) -> Path:
    """Write a plan as ``.npz``, ``.csv`` or MJCF ``<keyframe>`` ``.xml`` (see the module
    docstring): the gripper trajectory and the FE block pose at each knot.

    Parameters
    ----------
    fe_model : fe_contact.Model, optional
        Gives the block pose; defaults to ``scene.scenario.model()``.

    Raises
    ------
    InputError
        Unknown suffix, or the scene source is not a file (for the mocap layout).
    SolverFailure
        An FE step did not converge.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".csv", ".xml"):
        raise InputError(f"plan export must be .npz, .csv or .xml, got {path.name}")
    m = scene.mj_model("export_plan")
    traj = gripper_trajectory(scene, m, commands, gripper, control_period)
    block = block_knots(scene, fe_model or scene.scenario.model(), commands)
    if suffix == ".npz":
        return atomic_write_npz(
            path, time=traj.time, mocap_pos=traj.mocap_pos, mocap_quat=traj.mocap_quat,
            upper_centre=traj.upper_centre, upper_yaw=traj.upper_yaw, block_pos=block.pos, block_quat=block.quat,
            lower_centre=block.lower_centre, lower_yaw=block.lower_yaw, gripper=np.array(gripper),
        )
    if suffix == ".csv":
        return atomic_write_bytes(path, _csv(traj, block))
    return atomic_write_bytes(path, keyframes_mjcf(m, traj, scene, block).encode())
