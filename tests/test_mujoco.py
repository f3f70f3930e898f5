"""MuJoCo bridge (issue 7): MJCF import, co-simulation coupler, rigid / flex
comparison, plan export and the ``pushplan mujoco`` CLI.

Expected values come from the scene as written (paper case 3, stated here by hand),
from the physics (normality rule of a sliding rigid body, isotropy), or from
MuJoCo's own kinematics; never from the bridge's output.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from fe_contact import Command, initial_state, step
from pushplan.cli import main
from pushplan.mujoco import (
    CoSimulation,
    compare,
    export_plan,
    open_scene,
    scene_from_mjcf,
)

ROOT = Path(__file__).resolve().parents[1]
SCENE_XML = ROOT / "scenarios" / "mujoco_push.xml"
SCENE_TOML = ROOT / "scenarios" / "mujoco_push.toml"

# What scenarios/mujoco_push.xml states (paper sect. 9, case 3), written independently.
MU_X, MU_Y = 0.3, 0.05          # <pair friction="0.05 0.3 ..."> : f1 along world y, f2 along world x
SIZE = (0.020, 0.020, 0.010)    # box half-sizes 0.01 0.01 0.005
YOUNG, POISSON = 210e9, 0.3     # <numeric> fields
PRESS = (0.0, 0.0, -0.1e-3)
PUSH = (0.32e-3 * math.cos(math.pi / 4), 0.32e-3 * math.sin(math.pi / 4), 0.0)
COARSE = {"elements": (4, 4, 2), "quadrature": 2}

POSE_TOL = 1e-12            # m: block pose MuJoCo shows vs the FE lower-face pose
YAW_TOL = 1e-12             # rad
COMMAND_TOL = 1e-12         # m / rad: gripper motion recovered as FE commands
COUPLED_VS_DIRECT = 1e-9    # relative: coupled FE run vs the same commands stepped directly
RIGID_TWIST_DEG = 0.5       # MuJoCo weld compliance at dt = 1 ms (0.34 deg measured, 0.006 deg at 0.25 ms)
FE_TWIST_MIN_DEG = 2.0      # coarse mesh: 13.8 deg after the first push, 3.05 deg after the fourth
FLEX_DEVIATION_DEG = 0.05   # isotropic flex: no anisotropic deviation
NORMALITY_TOL_DEG = 1.0     # force-driven rigid box vs the elliptic normality rule


def _with_text(tmp_path: Path, old: str, new: str, name: str = "scene.xml") -> Path:
    text = SCENE_XML.read_text()
    assert text.count(old) == 1, old
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return path


# ------------------------------------------------------------------------- import


def test_import_gives_friction_size_and_material_of_the_mjcf():
    scene = scene_from_mjcf(SCENE_XML)
    s = scene.scenario
    assert (s.mu_x, s.mu_y) == pytest.approx((MU_X, MU_Y), rel=1e-15)
    assert s.size == pytest.approx(SIZE, rel=1e-15)
    assert s.angle_deg == 0.0
    assert (s.young, s.poisson) == (YOUNG, POISSON)
    assert scene.pair == "block_floor"
    assert scene.lower_centre == pytest.approx([0.0, 0.0, 0.0], abs=1e-15)
    # what MJCF cannot say is reported, not invented silently
    assert {"block.elements", "block.quadrature", "solver", "load"} <= set(scene.not_from_mjcf)


def test_swapped_pair_friction_swaps_mu(tmp_path):
    path = _with_text(tmp_path, 'friction="0.05 0.3 ', 'friction="0.3 0.05 ')
    s = scene_from_mjcf(path).scenario
    assert (s.mu_x, s.mu_y) == pytest.approx((MU_Y, MU_X), rel=1e-15)


def test_yawed_block_keeps_the_friction_axes_world_fixed(tmp_path):
    # MuJoCo's plane-box contact frame ignores body yaw, so in the block's frame
    # the orthotropy axis along world x sits at -30 deg.
    path = _with_text(tmp_path, '<body name="block" pos="0 0 0.005">',
                      '<body name="block" pos="0 0 0.005" euler="0 0 30">')
    scene = scene_from_mjcf(path)
    s = scene.scenario
    assert scene.yaw == pytest.approx(math.radians(30.0), abs=1e-12)
    assert s.angle_deg == pytest.approx(-30.0, abs=1e-9)
    assert (s.mu_x, s.mu_y) == pytest.approx((MU_X, MU_Y), rel=1e-15)  # mu_x still acts along world x


@pytest.mark.parametrize(
    "old, new, kwargs, message",
    [
        (None, None, {"block": "brick"}, "brick"),
        (None, None, {"floor": "block_geom"}, "must be a plane"),
        ('<geom name="floor" type="plane"', '<geom name="floor" type="plane" euler="10 0 0"', {}, r"not world \+z"),
        ('<numeric name="pushplan_young" data="210e9"/>', "", {}, "pushplan_young"),
        ('<body name="block" pos="0 0 0.005">', '<body name="block" pos="0 0 0.02">', {}, "does not touch"),
    ],
)
def test_import_rejects_bad_scenes(tmp_path, old, new, kwargs, message):
    path = SCENE_XML if old is None else _with_text(tmp_path, old, new)
    with pytest.raises(ValueError, match=message):
        scene_from_mjcf(path, **kwargs)


# ------------------------------------------------------------------ co-simulation


def test_cosimulation_writes_the_fe_lower_face_pose_every_period():
    scene, settings = open_scene(SCENE_TOML)
    m = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    fe = scene.scenario.model(**COARSE)
    n_sub = round(settings.control_period / m.opt.timestep)
    geom, half = m.geom("block_geom").id, SIZE[2] / 2
    lower0 = d.geom_xpos[geom] - [0.0, 0.0, half]
    coupler = CoSimulation(m, d, scene, "gripper", settings.control_period, fe)
    increments = [PRESS] + [PUSH] * 4
    t0 = time.perf_counter()
    for inc in increments:  # an ordinary MuJoCo loop moving the mocap gripper
        start = d.mocap_pos[0].copy()
        reports = []
        for j in range(1, n_sub + 1):
            d.mocap_pos[0] = start + np.array(inc) * j / n_sub
            mujoco.mj_step(m, d)
            rep = coupler.update()
            if rep is not None:
                reports.append(rep)
        assert len(reports) == 1 and reports[0].converged
        rep = reports[0]
        assert [rep.command.dx, rep.command.dy, rep.command.dz] == pytest.approx(inc, abs=COMMAND_TOL)
        R = d.geom_xmat[geom].reshape(3, 3)
        np.testing.assert_allclose(d.geom_xpos[geom] - R[:, 2] * half, lower0 + rep.lower_centroid, atol=POSE_TOL)
        assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(rep.lower_yaw, abs=YAW_TOL)
    rate = len(increments) / (time.perf_counter() - t0)
    print(f"\nco-simulation rate: {rate:.2f} control periods/s ({n_sub} MuJoCo steps per period, "
          f"FE mesh {COARSE['elements']}, quadrature {COARSE['quadrature']})")
    # coupling adds nothing: same as stepping the FE model with the gripper increments
    state = initial_state(fe)
    for inc in increments:
        state, _ = step(fe, state, Command(*inc))
    scale = np.abs(state.displacement).max()
    np.testing.assert_allclose(coupler.state.displacement, state.displacement, atol=COUPLED_VS_DIRECT * scale)
    # physics: the lower face lags toward the low-friction y axis (counter-clockwise of 45 deg)
    assert math.degrees(coupler.reports[-1].twist) > FE_TWIST_MIN_DEG


def test_offset_rotating_gripper_keyframes_and_coupler_recover_the_commands(tmp_path):
    offset = 0.004  # gripper origin 4 mm along +x from the upper-face centre
    path = _with_text(tmp_path, '<body name="gripper" mocap="true" pos="0 0 0.01">',
                      f'<body name="gripper" mocap="true" pos="{offset} 0 0.01">')
    scene = scene_from_mjcf(path, base=open_scene(SCENE_TOML)[0].scenario)
    commands = [Command(*PRESS), Command(*PUSH, dtheta=0.01), Command(*PUSH, dtheta=-0.004)]
    period = 0.01
    fe = scene.scenario.model(elements=(2, 2, 1))
    export_plan(tmp_path / "plan.npz", scene, commands, "gripper", period, fe)
    export_plan(tmp_path / "plan.xml", scene, commands, "gripper", period, fe)
    # expected knots: upper-face centre = start + sum of increments; gripper = centre + R(yaw) (offset, 0, 0)
    centre = np.vstack([[0.0, 0.0, 0.01], [0.0, 0.0, 0.01] + np.cumsum([[c.dx, c.dy, c.dz] for c in commands], 0)])
    yaw = np.concatenate([[0.0], np.cumsum([c.dtheta for c in commands])])
    grip = centre + offset * np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)])
    quat = np.column_stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)])
    z = np.load(tmp_path / "plan.npz")
    np.testing.assert_allclose(z["time"], period * np.arange(len(commands) + 1), rtol=1e-15)
    np.testing.assert_allclose(z["mocap_pos"], grip, atol=1e-15)
    np.testing.assert_allclose(z["mocap_quat"], quat, atol=1e-15)
    np.testing.assert_allclose(z["upper_centre"], centre, atol=1e-15)
    # the keyframes load into the scene
    text = path.read_text()
    i = text.rindex("</mujoco>")
    m = mujoco.MjModel.from_xml_string(text[:i] + f'<include file="{tmp_path / "plan.xml"}"/>\n' + text[i:])
    assert m.nkey == len(commands) + 1
    np.testing.assert_allclose(m.key_mpos, grip, atol=1e-15)
    np.testing.assert_allclose(m.key_time, z["time"], rtol=1e-15)
    # replaying the keyframes through the coupler gives back the commands
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    coupler = CoSimulation(m, d, scene, "gripper", m.opt.timestep, scene.scenario.model(elements=(2, 2, 1)))
    for k in range(1, m.nkey):
        d.mocap_pos[0], d.mocap_quat[0] = m.key_mpos[k], m.key_mquat[k]
        mujoco.mj_step(m, d)
        rep = coupler.update()
        c = commands[k - 1]
        assert rep.converged
        assert [rep.command.dx, rep.command.dy, rep.command.dz, rep.command.dtheta] == pytest.approx(
            [c.dx, c.dy, c.dz, c.dtheta], abs=COMMAND_TOL)


# --------------------------------------------------------------------- comparison


def test_comparison_rigid_weld_no_twist_fe_twist_flex_isotropic(tmp_path):
    scene, settings = open_scene(SCENE_TOML)
    result = compare(scene, settings=settings, fe_model=scene.scenario.model(**COARSE), out_dir=tmp_path).to_dict()
    steps = {name: res["steps"][1:] for name, res in result["models"].items()}  # the four pushes
    assert "cannot turn with the block" in result["limitations"][0]
    fe_twist = np.array([r["twist_deg"] for r in steps["fe"]])
    assert np.all(fe_twist > FE_TWIST_MIN_DEG)
    for r in steps["rigid_weld"]:
        assert abs(r["twist_deg"]) < RIGID_TWIST_DEG and abs(r["deviation_deg"]) < RIGID_TWIST_DEG
    # yaw in the summary: the final and largest of the steps' lower-face yaw
    for _name, res in result["models"].items():
        yaws = [r["lower_yaw_deg"] for r in res["steps"]]
        assert res["summary"]["final_lower_yaw_deg"] == yaws[-1]
        assert res["summary"]["max_abs_lower_yaw_deg"] == max(abs(v) for v in yaws)
    for r in steps["flex_isotropic"]:
        assert abs(r["deviation_deg"]) < FLEX_DEVIATION_DEG
        assert np.linalg.norm(r["lower"][:2]) > 0.5 * np.linalg.norm(r["drive"][:2])  # it did slide
    # a force-driven rigid box slides along the normal of the friction ellipse: v ~ M^-2 F
    predicted = math.degrees(math.atan2(PUSH[1] / MU_Y**2, PUSH[0] / MU_X**2)) - 45.0
    for r in steps["rigid_force"]:
        assert r["deviation_deg"] == pytest.approx(predicted, abs=NORMALITY_TOL_DEG)
        assert abs(r["twist_deg"]) < RIGID_TWIST_DEG  # a rigid body does not twist
    written = json.loads((tmp_path / "comparison.json").read_text())
    assert set(written["models"]) == {"fe", "rigid_weld", "rigid_force", "flex_isotropic"}
    assert (tmp_path / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # isotropy, not symmetry: off the block's diagonal the flex still follows the push
    off_axis = (0.32e-3 * math.cos(math.radians(30)), 0.32e-3 * math.sin(math.radians(30)), 0.0)
    flex = compare(scene, [Command(*PRESS), Command(*off_axis), Command(*off_axis)], settings,
                   models=("flex_isotropic",)).to_dict()["models"]["flex_isotropic"]["steps"]
    assert all(abs(r["deviation_deg"]) < FLEX_DEVIATION_DEG for r in flex[1:])


# ---------------------------------------------------------------------------- CLI


def test_cli_cosim_compare_export_and_bad_input(tmp_path, capsys):
    coarse = ["--elements", "4", "4", "2", "--quadrature", "2"]
    assert main(["mujoco", "cosim", str(SCENE_TOML), "--out", str(tmp_path / "co"), *coarse]) == 0
    record = json.loads((tmp_path / "co" / "cosim.json").read_text())
    assert record["status"] == "completed" and len(record["periods"]) == 5
    for p in record["periods"]:
        # the scene's block rests at the world origin unyawed: world and FE frames coincide
        np.testing.assert_allclose(p["mujoco_lower_centre"], p["fe_frame"]["lower_centroid"], atol=POSE_TOL)
    assert (tmp_path / "co" / "cosim.rrd").stat().st_size > 0
    assert "control periods/s" in capsys.readouterr().out
    assert main(["mujoco", "compare", str(SCENE_TOML), "--out", str(tmp_path / "cmp"), "--no-flex", *coarse]) == 0
    assert set(json.loads((tmp_path / "cmp" / "comparison.json").read_text())["models"]) == {
        "fe", "rigid_weld", "rigid_force"}
    assert main(["mujoco", "export", str(SCENE_TOML), "--out", str(tmp_path / "plan.npz"), *coarse]) == 0
    assert np.load(tmp_path / "plan.npz")["mocap_pos"].shape == (6, 3)
    assert main(["mujoco", "import", str(tmp_path / "missing.xml")]) == 2
    assert main(["mujoco", "export", str(SCENE_TOML), "--out", str(tmp_path / "plan.txt")]) == 2
    assert main(["mujoco", "cosim", str(SCENE_XML), "--out", str(tmp_path / "x")]) == 2  # no commands
    assert "no commands" in capsys.readouterr().err


def test_mujoco_stays_out_of_fe_contact_and_the_cli_parser():
    code = ("import sys, fe_contact, pushplan.cli; pushplan.cli.build_parser(); "
            "print('mujoco' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
    imports = re.compile(r"^\s*(import|from)\s+mujoco\b", re.MULTILINE)
    assert not any(imports.search(p.read_text()) for p in (ROOT / "fe_contact").glob("*.py"))


# ----------------------------------------------------------------------- settings


def test_bridge_settings_round_trip_and_named_errors():
    from pushplan.config.mujoco import BridgeSettings, bridge_settings
    from pushplan.config.scenario import load_scenario
    from pushplan.errors import InputError

    table = load_scenario(SCENE_TOML).extra["mujoco"]
    settings = bridge_settings(table)
    assert settings.flex_points == (3, 3, 2) and settings.force_factor == 1.2
    assert bridge_settings(settings.to_dict()) == settings
    custom = BridgeSettings(scene="s.xml", gripper="hand", control_period=0.01, settle_time=0.0,
                            flex_points=(4, 3, 2), flex_mu=0.2, force_factor=1.5)
    assert bridge_settings(custom.to_dict()) == custom
    assert bridge_settings({}) == BridgeSettings()
    for key, value, message in [
        ("force_factor", 1.0, "mujoco.force_factor must be > 1.0, got 1.0"),
        ("control_period", -1, "mujoco.control_period must be > 0, got -1"),
        ("settle_time", -0.1, "mujoco.settle_time must be >= 0"),
        ("flex_points", [3, 1, 2], r"mujoco.flex_points\[1\] must be >= 2, got 1"),
        ("flex_mu", "high", "mujoco.flex_mu must be a number"),
        ("gripper", 3, "mujoco.gripper must be a string"),
        ("speed", 1.0, "unknown key mujoco.speed"),
    ]:
        with pytest.raises(InputError, match=message):
            bridge_settings({**table, key: value})
