"""A stiff arm reaches what a mocap gripper reaches (issue 40 item 5's acceptance):
the shipped gantry (kp = 2e5 N/m) presses a soft block (E 8 MPa, 50 x 35 x 20 mm) by
0.5 mm and pushes it 2 mm at 30 deg, coupled with ``stiffness=True``.  The truth is
the same coupling driven by a mocap gripper along the command (no arm).  With integral
action, or with the coupling's reaction fed forward, the arm's run ends at the mocap
run's block pose to 1 % of the block's travel with no period-to-period oscillation of
the gripper force above 1 %; the P-only arm sags by F / kp and misses by far more."""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from pushplan.errors import InputError
from pushplan.mujoco import PositionController, attach, open_scene, scene_from_mjcf
from pushplan.mujoco.stiffness import CouplingWarning, oscillates

ROOT = Path(__file__).resolve().parents[1]
ARM_TOML = ROOT / "scenarios" / "mujoco_arm.toml"
ARM_XML = ROOT / "scenarios" / "mujoco_arm.xml"
SAME_POSE = 0.01
"""Final block position, arm run against mocap run, relative to the block's travel (the issue's 1 %)."""
STEADY = 0.01
"""Largest period-to-period change of the gripper force over the hold, relative (the issue's 1 %)."""
KI = 300.0
"""1/s: below bound (2) of pushplan.mujoco.arm for the 1.7 kg x carriage (686 1/s)."""
PRESS, PUSH, HOLD = 20, 50, 20
"""Periods: press 0.5 mm, push 2 mm at 30 deg, hold."""


def _scene_xml(mocap: bool) -> str:
    """The arm scene with the soft block (E 8 MPa, 50 x 35 x 20 mm) at half the timestep
    (omega dt of the stiffened quill is 2.1 at 1 ms: condition (3) of .stiffness); with
    ``mocap`` the gantry is replaced by a mocap hand at the same place."""
    text = (ARM_XML.read_text().replace('data="0.5e6"', 'data="8e6"')
            .replace('<body name="block" pos="0 0 0.005">', '<body name="block" pos="0 0 0.01">')
            .replace('size="0.01 0.01 0.005" density', 'size="0.025 0.0175 0.01" density')
            .replace('<body name="hand" pos="0 0 -0.09">', '<body name="hand" pos="0 0 -0.08">')
            .replace('timestep="0.001"', 'timestep="0.0005"'))
    if mocap:
        start, end = text.index('<body name="carriage_x"'), text.index("</worldbody>")
        text = text[:start] + '<body name="hand" mocap="true" pos="0 0 0.02"/>\n' + text[end:]
        start, end = text.index("<actuator>"), text.index("</sensor>") + len("</sensor>")
        text = text[:start] + text[end:]
    return text


def _run(tmp_path: Path, arm: str | None, ki: float = KI, elements=(2, 2, 1)):
    """Gripper forces (world, N) per period, final block (position (3,), yaw), the hand's
    final offset from its command (m) and MuJoCo's model; ``arm`` None drives a mocap hand,
    else "P" (the shipped PD servo), "PI" (integral action) or "FF" (reaction fed forward)."""
    xml = tmp_path / f"{arm or 'mocap'}.xml"
    xml.write_text(_scene_xml(arm is None))
    base, settings = open_scene(ARM_TOML)
    scene = scene_from_mjcf(xml, base=base.scenario)
    m = mujoco.MjModel.from_xml_path(str(xml))
    d = mujoco.MjData(m)
    coupler = attach(m, d, scene, gripper="hand", fe_model=scene.scenario.model(elements=elements),
                     stiffness=arm is not None)
    controller = None if arm is None else PositionController(
        m, ki=ki if arm == "PI" else 0.0, coupler=coupler if arm == "FF" else None)
    a = np.radians(30.0)
    steps = [[0, 0, -2.5e-5]] * PRESS + [[4e-5 * np.cos(a), 4e-5 * np.sin(a), 0]] * PUSH + [[0, 0, 0]] * HOLD
    plan = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    n_sub = round(settings.control_period / m.opt.timestep)
    hand0 = d.mocap_pos[0].copy() if arm is None else None
    forces = []
    try:
        for k in range(len(steps)):
            for j in range(1, n_sub + 1):
                reference = plan[k] + (plan[k + 1] - plan[k]) * j / n_sub
                if controller is None:
                    d.mocap_pos[0] = hand0 + reference
                else:
                    controller(d, reference)
                mujoco.mj_step(m, d)
            assert coupler.couple().converged
            forces.append(coupler.gripper_force.copy())
    finally:
        coupler.close()
    offset = (d.mocap_pos[0] - hand0 if arm is None else d.qpos[7:10]) - plan[-1]
    return np.array(forces), (coupler.lower_displacement.copy(), coupler.lower_yaw), offset, m


@pytest.fixture(scope="module")
def mocap(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("mocap"), None)


def _steady(forces: np.ndarray) -> float:
    hold = forces[-HOLD:]
    return float((np.linalg.norm(np.diff(hold, axis=0), axis=1) / np.linalg.norm(hold[1:], axis=1)).max())


@pytest.mark.parametrize("arm", ["PI", "FF"])
def test_the_stiff_arm_ends_at_the_mocap_runs_block_pose(tmp_path, mocap, arm):
    with warnings.catch_warnings():
        warnings.simplefilter("error", CouplingWarning)  # no oscillation, condition (3) holds
        forces, (position, yaw), offset, _ = _run(tmp_path, arm)
    truth_forces, (truth_position, truth_yaw), _, _ = mocap
    travel = np.linalg.norm(truth_position[:2])
    assert travel > 0.5e-3  # m: the block slides, a real push
    assert np.linalg.norm(position - truth_position) <= SAME_POSE * travel
    assert abs(yaw - truth_yaw) * 0.025 <= SAME_POSE * travel  # the yaw at the block's half length
    assert np.linalg.norm(offset) < 1e-8  # m: at rest at its command (integral / feed-forward)
    assert not any(oscillates(list(forces[k - 4:k])) for k in range(4, len(forces) + 1))
    assert _steady(forces) <= STEADY
    assert np.linalg.norm(forces[-1] - truth_forces[-1]) <= 0.01 * np.linalg.norm(truth_forces[-1])  # the same load


def test_the_p_only_arm_sags_by_its_load_over_kp(tmp_path, mocap):
    """The shipped PD servo alone: off its command by -F_g / kp at rest, pressing with a
    fraction of the mocap run's force, and missing its block pose by far more than 1 %."""
    forces, (position, _), offset, m = _run(tmp_path, "P")
    truth_forces, (truth_position, _), _, _ = mocap
    np.testing.assert_allclose(offset, -forces[-1] / m.actuator_gainprm[:3, 0], rtol=1e-3)
    assert abs(forces[PRESS - 1, 2]) < 0.3 * abs(truth_forces[PRESS - 1, 2])
    assert np.linalg.norm(position - truth_position) > 10 * SAME_POSE * np.linalg.norm(truth_position[:2])


def test_too_much_integral_gain_oscillates_and_the_coupler_says_so(tmp_path, monkeypatch):
    """Above bound (2) of pushplan.mujoco.arm (686 1/s for the x carriage) the loop is unstable."""
    monkeypatch.chdir(tmp_path)  # a MUJOCO_LOG.TXT, should MuJoCo's step blow up, lands here
    with pytest.warns(CouplingWarning, match="alternates period to period"):
        _run(tmp_path, "PI", ki=1000.0)


def test_the_controller_refuses_what_it_cannot_drive():
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint name="j" type="slide"/><geom size="0.1" mass="1"/></body></worldbody>'
        '<actuator><motor joint="j"/></actuator></mujoco>')
    with pytest.raises(InputError, match="actuator '#0' is not a <position> actuator"):
        PositionController(m)
    with pytest.raises(InputError, match="ki must be"):
        PositionController(mujoco.MjModel.from_xml_path(str(ARM_XML)), ki=-1.0)
