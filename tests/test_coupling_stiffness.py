"""The coupling with a stiff arm (issue 40 item 5): the shipped gantry (kp = 2e5 N/m)
on the arm scene's block made stiff (E 8 MPa: about 3.7e5 N/m at the gripper, above kp).
Explicit, the gripper force alternates period to period and the coupler warns; with
the condensed stiffness at the gripper, the arm settles into its static equilibrium
with the FE block (hand offset = -F_g / kp, from MuJoCo's own actuator gains) with no
oscillation.  Expected values from MuJoCo's state and the FE reports."""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from pushplan.mujoco import attach, open_scene, scene_from_mjcf
from pushplan.mujoco.stiffness import CouplingWarning, oscillates

ROOT = Path(__file__).resolve().parents[1]
ARM_TOML = ROOT / "scenarios" / "mujoco_arm.toml"
ARM_XML = ROOT / "scenarios" / "mujoco_arm.xml"
STEADY = 0.01
"""Largest period-to-period change of the gripper force over the hold, relative (the issue's 1 %)."""
EQUILIBRIUM = 1e-3
"""The hand's offset from its command against -F_g / kp, relative."""


def _stiff_arm(tmp_path: Path, stiffness: bool, push: int = 15, hold: int = 15):
    """Press 0.5 mm in 20 periods, push ``push`` x 0.02 mm at 30 deg, hold ``hold`` periods;
    the gripper forces (world, N) and the final state."""
    xml = tmp_path / "stiff_arm.xml"
    xml.write_text(ARM_XML.read_text().replace('name="pushplan_young" data="0.5e6"', 'name="pushplan_young" data="8e6"'))
    scene, settings = open_scene(ARM_TOML)
    scene = scene_from_mjcf(xml, base=scene.scenario)
    assert scene.scenario.young == 8e6
    m = mujoco.MjModel.from_xml_path(str(xml))
    d = mujoco.MjData(m)
    coupler = attach(m, d, scene, gripper="hand", fe_model=scene.scenario.model(elements=(2, 2, 1)),
                     stiffness=stiffness)
    a = np.radians(30.0)
    steps = [[0, 0, -2.5e-5]] * 20 + [[2e-5 * np.cos(a), 2e-5 * np.sin(a), 0]] * push + [[0, 0, 0]] * hold
    plan = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    n_sub = round(settings.control_period / m.opt.timestep)
    forces = []
    try:
        for k in range(len(steps)):
            for j in range(1, n_sub + 1):
                d.ctrl[:] = plan[k] + (plan[k + 1] - plan[k]) * j / n_sub
                mujoco.mj_step(m, d)
            assert coupler.couple().converged
            forces.append(coupler.gripper_force.copy())
    finally:
        coupler.close()
    return m, d, coupler, plan, np.array(forces)


def test_the_explicit_coupling_oscillates_and_warns(tmp_path):
    with pytest.warns(CouplingWarning, match="alternates period to period"):
        _, _, coupler, _, forces = _stiff_arm(tmp_path, stiffness=False, push=0, hold=6)
    assert oscillates(list(forces[-4:]))
    assert np.abs(np.diff(forces[-4:, 2])).min() > 0.5 * np.abs(forces[-4:, 2]).max()  # pressing, then separated


def test_the_condensed_stiffness_settles_the_stiff_arm(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", CouplingWarning)  # no oscillation, condition (3) holds
        m, d, coupler, plan, forces = _stiff_arm(tmp_path, stiffness=True)
    hold = forces[-15:]
    change = np.linalg.norm(np.diff(hold, axis=0), axis=1) / np.linalg.norm(hold[1:], axis=1)
    assert change.max() <= STEADY
    assert np.linalg.norm(forces[-1]) > 20.0  # N: a real press, not a graze
    kp = m.actuator_gainprm[:3, 0]
    np.testing.assert_allclose(d.qpos[7:10] - plan[-1], -coupler.gripper_force / kp, rtol=EQUILIBRIUM)
    # the stiffness is the FE's: symmetric positive in z, about E A / h of the block
    k = coupler.stiffness
    assert 1e5 < k[2, 2] < 2 * 8e6 * 4e-4 / 0.01
    assert mujoco.get_mjcb_passive() is None  # close() gave the callback back
