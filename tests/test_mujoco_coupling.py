"""Two-way coupling in a user's own MuJoCo loop (issue 33): the example gantry arm
pushing the FE block, and a hand-written ``mj_step`` + ``couple()`` loop against
``pushplan mujoco cosim``.

Expected values come from MuJoCo's own state (geom poses, sensor data, joint
positions, the actuators' gain) and the FE reports, never from the coupler's output
alone."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from pushplan.cli import main
from pushplan.errors import InputError
from pushplan.mujoco import attach, open_scene, run_cosimulation, scene_from_mjcf
from pushplan.mujoco.scene import block_geom_pose

ROOT = Path(__file__).resolve().parents[1]
ARM_TOML = ROOT / "scenarios" / "mujoco_arm.toml"
ARM_XML = ROOT / "scenarios" / "mujoco_arm.xml"
PUSH_TOML = ROOT / "scenarios" / "mujoco_push.toml"
TINY = (2, 2, 1)
HOLD_TOL = 1e-9       # m, block pose in MuJoCo vs the FE's, inside every period
SENSOR_REL = 1e-6     # wrist sensor vs the FE gripper force, relative
SAME_POSE = 1e-9      # m, user loop vs cosim


def _arm_run(periods: int | None = None, xml: Path = ARM_XML):
    """The arm scene's planned push through a user loop: position/PD actuators track
    the planned hand path (linear within a period), ``couple()`` once per period."""
    scene, settings = open_scene(ARM_TOML)
    if xml != ARM_XML:
        scene = scene_from_mjcf(xml, base=scene.scenario)
    m = mujoco.MjModel.from_xml_path(str(xml))
    d = mujoco.MjData(m)
    coupler = attach(m, d, scene, gripper="hand", fe_model=scene.scenario.model(elements=TINY))
    commands = scene.scenario.commands[:periods]
    plan = np.vstack([np.zeros(3), np.cumsum(scene.to_world([[c.dx, c.dy, c.dz] for c in commands]), axis=0)])
    n_sub = round(settings.control_period / m.opt.timestep)
    site = m.site("wrist").id
    out = {"hold": 0.0, "sensor": 0.0, "torque": 0.0, "tracking": 0.0}
    hand = m.body("hand").id
    for k in range(len(commands)):
        for j in range(1, n_sub + 1):
            d.ctrl[:] = plan[k] + (plan[k + 1] - plan[k]) * j / n_sub
            mujoco.mj_step(m, d)
            low, _, yaw = block_geom_pose(m, d, scene)
            fe_low = scene.lower_centre + scene.to_world(coupler.lower_displacement)
            out["hold"] = max(out["hold"], np.abs(low - fe_low).max(),
                              abs(yaw - scene.yaw - coupler.lower_yaw) * max(scene.scenario.size))
            # the wrist sensor, in the world frame, against the FE gripper force in force
            force = d.site_xmat[site].reshape(3, 3) @ d.sensordata[0:3]
            ref = coupler.gripper_force
            out["sensor"] = max(out["sensor"], np.linalg.norm(force - ref) / np.linalg.norm(ref)) if k else 0.0
            # the torque sensor: the gripper's moment (about the hand's origin) carried to the site
            torque = d.site_xmat[site].reshape(3, 3) @ d.sensordata[3:6]
            moment = coupler.gripper_moment + np.cross(d.xpos[hand] - d.site_xpos[site], ref)
            scale = np.linalg.norm(ref) * max(scene.scenario.size)  # N m: a zero moment is exact to rounding only
            out["torque"] = max(out["torque"], np.linalg.norm(torque - moment) / scale) if k else 0.0
        rep = coupler.couple()
        assert rep.converged, rep.message
        out["tracking"] = max(out["tracking"], np.abs(d.qpos[-3:] - plan[k + 1]).max())
    return m, d, scene, coupler, plan, out


def test_arm_pushes_the_fe_block_over_200_periods():
    m, d, scene, coupler, plan, out = _arm_run()
    assert len(coupler.reports) == 200
    assert out["hold"] <= HOLD_TOL
    assert out["sensor"] <= SENSOR_REL and out["torque"] <= SENSOR_REL
    np.testing.assert_allclose(d.userdata[9:12], coupler.gripper_moment, rtol=1e-15)
    # the arm feels the block: at rest its joints sit off their reference by the FE reaction / kp
    kp = m.actuator_gainprm[:, 0]
    np.testing.assert_allclose(d.qpos[7:10] - plan[-1], -coupler.gripper_force / kp, rtol=1e-3)
    assert np.linalg.norm(coupler.gripper_force) > 1.0  # N: a real push, not a graze
    # and tracks the planned push: 3 mm at 30 deg, within the compliance F / kp
    travel = np.linalg.norm(plan[-1][:2])
    assert travel == pytest.approx(3e-3, rel=1e-12)
    assert out["tracking"] < 1.5 * np.abs(coupler.gripper_force).max() / kp.min() < 0.03 * travel
    # the block slid (the FE lower face travelled most of the push)
    assert np.linalg.norm(coupler.lower_displacement[:2]) > 0.5 * travel
    print(f"\narm: hold {out['hold']:.2e} m, sensor {out['sensor']:.2e} rel, torque {out['torque']:.2e} rel, tracking {out['tracking']:.2e} m, "
          f"final F_g {coupler.gripper_force} N, lower {coupler.lower_displacement * 1e3} mm")


def test_arm_coupling_on_a_yawed_scene_with_turned_friction_axes(tmp_path):
    """The issue's own kind of scene: block off the origin yawed 25 deg, friction axes
    turned by the numeric, the hand yawed with it; the block turns (it yaws) and is
    still held, and the wrist still reads the FE force."""
    text = ARM_XML.read_text()
    for old, new in (
        ('<body name="block" pos="0 0 0.005">', '<body name="block" pos="0.013 -0.027 0.005" euler="0 0 25">'),
        ('<body name="carriage_x" pos="0 0 0.1"', '<body name="carriage_x" pos="0.013 -0.027 0.1"'),
        ('<body name="hand" pos="0 0 -0.09">', '<body name="hand" pos="0 0 -0.09" euler="0 0 25">'),
        ('<numeric name="pushplan_poisson" data="0.3"/>',
         '<numeric name="pushplan_poisson" data="0.3"/><numeric name="pushplan_friction_angle" data="10"/>'),
    ):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "yawed_arm.xml"
    path.write_text(text)
    m, d, scene, coupler, plan, out = _arm_run(60, path)
    assert scene.scenario.angle_deg == pytest.approx(-15.0, abs=1e-9)  # 10 deg turned, seen from a 25 deg block
    assert abs(coupler.lower_yaw) > 1e-3  # rad: the block turns, and MuJoCo shows it turned
    assert out["hold"] <= HOLD_TOL and out["sensor"] <= SENSOR_REL


def test_a_user_loop_of_mj_step_and_couple_reproduces_cosim(tmp_path):
    scene, settings = open_scene(PUSH_TOML)
    fe = scene.scenario.model(elements=TINY)
    commands = list(scene.scenario.commands)
    period = 0.01
    record = run_cosimulation(scene, commands, "gripper", period, fe)
    # the user's loop: their mocap path (linear per command), mj_step, couple()
    m = mujoco.MjModel.from_xml_path(scene.source)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    coupler = attach(m, d, scene, fe_model=scene.scenario.model(elements=TINY))
    n_sub = round(period / m.opt.timestep)
    for k, c in enumerate(commands):
        start = d.mocap_pos[0].copy()
        for j in range(1, n_sub + 1):
            d.mocap_pos[0] = start + scene.to_world([c.dx, c.dy, c.dz]) * j / n_sub
            mujoco.mj_step(m, d)
        coupler.couple()
        low, _, yaw = block_geom_pose(m, d, scene)
        p = record.periods[k]
        assert np.abs(low - p.mujoco_lower_centre).max() <= SAME_POSE
        assert abs(yaw - p.mujoco_yaw) <= SAME_POSE / max(scene.scenario.size)
    assert len(record.periods) == len(commands)
    # and the CLI's cosim wrote those poses
    toml = tmp_path / "push.toml"
    toml.write_text(PUSH_TOML.read_text().replace('scene = "mujoco_push.xml"', f'scene = "{scene.source}"')
                    .replace("control_period = 0.05", "control_period = 0.01"))
    assert main(["mujoco", "cosim", str(toml), "--elements", *map(str, TINY), "--out", str(tmp_path / "c"),
                 "--no-rerun"]) == 0
    last = json.loads((tmp_path / "c" / "cosim.json").read_text())["periods"][-1]
    assert np.abs(np.array(last["mujoco_lower_centre"]) - low).max() <= SAME_POSE


def test_a_gripper_that_collides_with_the_block_is_refused(tmp_path):
    text = ARM_XML.read_text().replace('<geom name="hand_pad" type="box"', '<geom name="hand_pad" type="box" '
                                       'contype="1" conaffinity="1"')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    scene, _ = open_scene(ARM_TOML)
    m = mujoco.MjModel.from_xml_path(str(path))
    with pytest.raises(InputError, match="'hand_pad' collides with the block"):
        attach(m, mujoco.MjData(m), scene, gripper="hand")
    # excluded, it is accepted
    path.write_text(text.replace("</contact>", '<exclude body1="hand" body2="block"/>\n  </contact>'))
    m = mujoco.MjModel.from_xml_path(str(path))
    attach(m, mujoco.MjData(m), scene, gripper="hand", fe_model=scene.scenario.model(elements=TINY))


def test_the_mjcf_density_gives_the_fe_weight_and_a_toml_density_wins_with_a_warning(tmp_path):
    from pushplan.errors import InputWarning
    from pushplan.mujoco import scene_from_mjcf

    volume = 0.02 * 0.02 * 0.01
    scene = scene_from_mjcf(ARM_XML)  # geom density="1100"
    assert scene.scenario.model(elements=TINY).weight == pytest.approx(1100 * 9.81 * volume, rel=1e-12)
    # a geom given by its mass: rho = m / V
    path = tmp_path / "mass.xml"
    path.write_text(ARM_XML.read_text().replace('density="1100"', 'mass="0.005"'))
    assert scene_from_mjcf(path).scenario.model(elements=TINY).weight == pytest.approx(0.005 * 9.81, rel=1e-12)
    # the scenario's density overrides, with one warning naming the key and both values
    base = open_scene(ARM_TOML)[0].scenario
    with pytest.warns(InputWarning, match=r"material.density = 1000 kg/m\^3 .* overrides .* 1100 kg/m\^3"):
        s = scene_from_mjcf(ARM_XML, base=replace(base, density=1000.0))
    assert s.scenario.density == 1000.0 and "material.density" not in s.from_mjcf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        same = scene_from_mjcf(ARM_XML, base=replace(base, density=1100.0))
    assert same.scenario.density == 1100.0


def test_unnamed_geoms_get_their_body_name_in_recording_paths():
    from pushplan.mujoco.cosim import _boxes

    m = mujoco.MjModel.from_xml_path(str(ARM_XML))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    names = set(_boxes(m, d))
    assert {"block_geom", "hand_pad", "carriage_x_geom2", "carriage_y_geom3"} <= names
    assert not any(n.startswith("#") for n in names)
