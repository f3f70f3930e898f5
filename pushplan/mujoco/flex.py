"""The MuJoCo flex block of the comparison: a 3D elastic flexcomp of the block's size
and material with isotropic friction (MuJoCo flex contacts take no anisotropy).

Flex elasticity in 3D needs ``integrator="discrete"`` and a flex cannot hang from a
mocap body, so the flex is pinned to a dynamic pad welded to a mocap gripper.  Its
face poses are measured like the FE model's (:mod:`fe_contact.stepping.pose`): tributary-area
weighted centroid displacement and best-fit yaw of the lower and upper grid faces.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fe_contact import Command, face_centroid_displacement, planar_yaw

from .frames import quat_z
from .mjmodel import mujoco_module
from .records import ComparisonStep
from .rigid import WELD_TIMECONST_STEPS
from .scene import MjcfScene
from .trajectory import GripperTrajectory

FLEX_RADIUS = 0.01
"""Flex vertex radius relative to the smallest grid spacing."""
FLEX_DAMPING = 1e-9
"""Flex Rayleigh damping, s: negligible, but it marks the flex as having passive forces
(MuJoCo 4.0 otherwise warns, and writes MUJOCO_LOG.TXT, that an elastic flex under the
discrete integrator has none)."""


def flex_mjcf(scene: MjcfScene, points: tuple[int, int, int], mu: float, timestep: float,
              gravity: np.ndarray) -> str:
    """MJCF of the isotropic flex comparison: a 3D grid flexcomp of the block's size
    and material, top layer pinned to a pad welded to a mocap ``gripper`` at the
    upper-face centre, on a plane with isotropic friction ``mu``."""
    s = scene.scenario
    spacing = [s.size[i] / (points[i] - 1) for i in range(3)]
    radius = FLEX_RADIUS * min(spacing)
    centre = scene.lower_centre + np.array([0.0, 0.0, s.size[2] / 2 + radius])
    up = scene.upper_centre + np.array([0.0, 0.0, radius])
    q = quat_z(scene.yaw)
    v = lambda a: " ".join(f"{x:.17g}" for x in a)  # noqa: E731
    nx, ny, nz = points
    return f"""<mujoco model="pushplan_flex">
  <option timestep="{timestep:.17g}" cone="elliptic" integrator="discrete" gravity="{v(gravity)}"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.01" pos="0 0 {scene.lower_centre[2]:.17g}" friction="{mu:.17g} 0 0"/>
    <body name="gripper" mocap="true" pos="{v(up)}" quat="{v(q)}"/>
    <body name="pad" pos="{v(centre)}" quat="{v(q)}">
      <freejoint/>
      <geom type="box" size="{radius:.6g} {radius:.6g} {radius:.6g}" mass="{scene.block_mass:.6g}"
            contype="0" conaffinity="0"/>
      <flexcomp name="block" type="grid" dim="3" count="{nx} {ny} {nz}" spacing="{v(spacing)}"
                radius="{radius:.6g}" mass="{scene.block_mass:.17g}" dof="full">
        <contact condim="3" friction="{mu:.17g} 0 0" priority="1" selfcollide="none"/>
        <elasticity young="{s.young:.17g}" poisson="{s.poisson:.17g}" damping="{FLEX_DAMPING:g}"/>
        <edge equality="false"/>
        <pin gridrange="0 0 {nz - 1} {nx - 1} {ny - 1} {nz - 1}"/>
      </flexcomp>
    </body>
  </worldbody>
  <equality><weld body1="gripper" body2="pad" solref="{WELD_TIMECONST_STEPS * timestep:.17g} 1"/></equality>
</mujoco>
"""


def _faces(scene: MjcfScene, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(lower ids, upper ids, FE-frame reference positions (n, 3), tributary weights (n,))
    of the flex grid vertices ``x0`` (n, 3): trapezoidal weights of a regular grid face,
    half on edges, a quarter at corners."""
    z = x0[:, 2]
    tol = 1e-9 * scene.scenario.size[2]
    lower = np.flatnonzero(np.isclose(z, z.min(), atol=tol))
    upper = np.flatnonzero(np.isclose(z, z.max(), atol=tol))
    local = scene.to_fe(x0 - scene.lower_centre)
    w = np.ones(x0.shape[0])
    for ax in (0, 1):
        edge = np.isclose(local[:, ax], local[:, ax].min()) | np.isclose(local[:, ax], local[:, ax].max())
        w[edge] *= 0.5
    return lower, upper, local, w


def flex_run(scene: MjcfScene, commands: Sequence[Command], traj: GripperTrajectory, n_move: int, n_settle: int,
             points: tuple[int, int, int], mu: float) -> tuple[ComparisonStep, ...]:
    """The flex block (:func:`flex_mjcf`, the scene's timestep and gravity) with its
    gripper following ``traj`` in ``n_move`` MuJoCo steps per command, held for
    ``n_settle``."""
    mj = mujoco_module()
    src = scene.mj_model("flex_run")
    m = mj.MjModel.from_xml_string(flex_mjcf(scene, points, mu, src.opt.timestep, src.opt.gravity))
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    x0 = d.flexvert_xpos.copy()
    lower, upper, local, w = _faces(scene, x0)
    g0 = np.array(m.body_pos[m.body("gripper").id])
    drive = traj.upper_centre - traj.upper_centre[0]
    turn = traj.upper_yaw - traj.upper_yaw[0]
    out, scale = [], max(scene.scenario.size)
    for k in range(len(commands)):
        for j in range(1, n_move + n_settle + 1):
            s = min(j / n_move, 1.0)
            d.mocap_pos[0] = g0 + (1 - s) * drive[k] + s * drive[k + 1]
            d.mocap_quat[0] = quat_z(scene.yaw + (1 - s) * turn[k] + s * turn[k + 1])
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        mj.mj_flex(m, d)
        x = d.flexvert_xpos
        disp = x - x0
        low = face_centroid_displacement(disp[lower], w[lower])
        up = face_centroid_displacement(disp[upper], w[upper])
        yaw = planar_yaw(local[lower], scene.to_fe(x[lower]), w[lower])
        out.append(ComparisonStep.measure(k + 1, drive[k + 1], up, low, yaw, scale))
    return tuple(out)
