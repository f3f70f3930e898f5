"""MuJoCo bridge, world frame and what goes back to MuJoCo (issue 22): a yawed box resting
exactly at its height, friction axes from a ``<custom>`` numeric, keyframes and CSV with
the block pose, FE forces in ``userdata`` and the gripper's ``xfrc_applied``, the co-simulation
recording's ``sim_time`` and boxes, planner targets in the world frame.

Expected values are stated by hand from the scene as written (a block at (13, -27) mm
yawed 3 deg), computed here from the FE model stepped directly, or read from MuJoCo's
own kinematics; never from the bridge's output.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from fe_contact import Command, initial_state, step
from pushplan.cli import main
from pushplan.config import parse_scenario
from pushplan.config.plan import parse_plan
from pushplan.errors import InputError
from pushplan.mujoco import CoSimulation, export_plan, run_cosimulation, scene_from_mjcf

ROOT = Path(__file__).resolve().parents[1]
SCENE_XML = ROOT / "scenarios" / "mujoco_push.xml"
SCENE_TOML = ROOT / "scenarios" / "mujoco_push.toml"

X0, Y0, HEIGHT = 0.013, -0.027, 0.010      # block rest position (m) and height
YAW0_DEG = 3.0                              # MuJoCo finds no contact at qpos0 at this yaw
MU_ALONG_WORLD_X, MU_ALONG_WORLD_Y = 0.3, 0.05   # <pair friction="0.05 0.3 ...">: f2 along x, f1 along y
PRESS = Command(0.0, 0.0, -0.1e-3)
PUSH = Command(0.32e-3 * math.cos(math.pi / 4), 0.32e-3 * math.sin(math.pi / 4), 0.0)
COARSE = (2, 2, 1)
POSE_TOL = 1e-12    # m
FORCE_REL = 1e-9    # forces written into MuJoCo vs the FE's, relative


def rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yawed_scene(tmp_path: Path, yaw_deg: float = YAW0_DEG, z: float = HEIGHT / 2, friction_angle=None,
                name: str = "yawed.xml") -> Path:
    """The scene (``nuserdata = 9``) with the block at (X0, Y0, z) yawed ``yaw_deg``, the
    gripper on its upper face and optionally ``pushplan_friction_angle``."""
    text = SCENE_XML.read_text()
    assert '<size nuserdata="9"/>' in text
    swaps = [
        ('<body name="block" pos="0 0 0.005">', f'<body name="block" pos="{X0} {Y0} {z!r}" euler="0 0 {yaw_deg}">'),
        ('<body name="gripper" mocap="true" pos="0 0 0.01">',
         f'<body name="gripper" mocap="true" pos="{X0} {Y0} {HEIGHT}" euler="0 0 {yaw_deg}">'),
    ]
    if friction_angle is not None:
        swaps.append(('<numeric name="pushplan_poisson" data="0.3"/>', '<numeric name="pushplan_poisson" '
                      f'data="0.3"/>\n    <numeric name="pushplan_friction_angle" data="{friction_angle}"/>'))
    for old, new in swaps:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------------- import


@pytest.mark.parametrize("friction_angle, mu_x, mu_y, angle_deg", [
    # floor axes turned 20 deg: the mu = 0.3 axis at 20 deg in the world, 17 deg from the block's x edge
    (20.0, MU_ALONG_WORLD_X, MU_ALONG_WORLD_Y, 17.0),
    # turned 50 deg: the 0.3 axis at 47 deg from x, so the 0.05 axis (at -43 deg) is the one nearer x
    (50.0, MU_ALONG_WORLD_Y, MU_ALONG_WORLD_X, -43.0),
    # no numeric: MuJoCo's own frame, the 0.3 axis along world x, -3 deg in the block frame
    (None, MU_ALONG_WORLD_X, MU_ALONG_WORLD_Y, -YAW0_DEG),
])
def test_yawed_box_resting_exactly_at_its_height_with_friction_axes_from_a_numeric(
        tmp_path, friction_angle, mu_x, mu_y, angle_deg):
    path = yawed_scene(tmp_path, friction_angle=friction_angle)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.ncon == 0  # the premise: MuJoCo itself drops the resting contacts here
    scene = scene_from_mjcf(path)
    s = scene.scenario
    assert (s.mu_x, s.mu_y) == (mu_x, mu_y)
    assert s.angle_deg == pytest.approx(angle_deg, abs=1e-9)
    assert scene.yaw == pytest.approx(math.radians(YAW0_DEG), abs=1e-12)
    np.testing.assert_allclose(scene.lower_centre, [X0, Y0, 0.0], atol=1e-15)
    # the import leaves the model's margins as they were
    assert m.geom_margin.max() == 0.0 and m.pair_margin.max() == 0.0


def test_resting_gap_tolerance_is_a_millionth_of_the_height(tmp_path):
    inside = yawed_scene(tmp_path, z=HEIGHT / 2 + 0.5e-6 * HEIGHT, name="inside.xml")
    assert scene_from_mjcf(inside).scenario.size[2] == pytest.approx(HEIGHT, rel=1e-15)
    outside = yawed_scene(tmp_path, z=HEIGHT / 2 + 2e-6 * HEIGHT, name="outside.xml")
    with pytest.raises(InputError, match="does not touch"):
        scene_from_mjcf(outside)


# ------------------------------------------------------------------------- export


def _fe_lower_poses(model, commands):
    """(K+1, 3) lower-face centroid displacements and (K+1,) yaws, FE frame, stepped here."""
    state, disp, yaw = initial_state(model), [np.zeros(3)], [0.0]
    for c in commands:
        state, rep = step(model, state, c)
        assert rep.converged
        disp.append(np.asarray(rep.lower_centroid, float))
        yaw.append(float(rep.lower_yaw))
    return np.array(disp), np.array(yaw)


def test_keyframes_npz_and_csv_hold_the_block_pose(tmp_path, capsys):
    path = yawed_scene(tmp_path)
    scene = scene_from_mjcf(path, base=parse_scenario({**_base_table(), "name": "x"}))
    commands = [PRESS, PUSH, PUSH]
    fe = scene.scenario.model(elements=COARSE, quadrature=2)
    for suffix in ("xml", "npz", "csv"):
        export_plan(tmp_path / f"plan.{suffix}", scene, commands, "gripper", 0.05, fe)
    disp, yaw = _fe_lower_poses(fe, commands)
    a0 = math.radians(YAW0_DEG)
    body = np.array([X0, Y0, HEIGHT / 2]) + disp @ rz(a0).T    # body origin at the box centre
    quat = np.column_stack([np.cos((a0 + yaw) / 2), 0 * yaw, 0 * yaw, np.sin((a0 + yaw) / 2)])
    # the keyframes load into the scene and MuJoCo puts the box where the FE block is
    text = path.read_text()
    i = text.rindex("</mujoco>")
    m = mujoco.MjModel.from_xml_string(text[:i] + f'<include file="{tmp_path / "plan.xml"}"/>\n' + text[i:])
    d = mujoco.MjData(m)
    geom = m.geom("block_geom").id
    assert m.nkey == len(commands) + 1
    for k in range(m.nkey):
        mujoco.mj_resetDataKeyframe(m, d, k)
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(d.geom_xpos[geom], body[k], atol=POSE_TOL)
        R = d.geom_xmat[geom].reshape(3, 3)
        assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(a0 + yaw[k], abs=1e-12)
    z = np.load(tmp_path / "plan.npz")
    np.testing.assert_allclose(z["block_pos"], body, atol=POSE_TOL)
    np.testing.assert_allclose(z["block_quat"], quat, atol=1e-15)
    np.testing.assert_allclose(z["lower_centre"], body - [0.0, 0.0, HEIGHT / 2], atol=POSE_TOL)
    # CSV: the documented header, the same numbers
    lines = (tmp_path / "plan.csv").read_text().splitlines()
    assert lines[0] == ("time,mocap_x,mocap_y,mocap_z,mocap_qw,mocap_qx,mocap_qy,mocap_qz,"
                        "upper_x,upper_y,upper_z,upper_yaw,block_x,block_y,block_z,block_qw,block_qx,block_qy,"
                        "block_qz,lower_x,lower_y,lower_z,lower_yaw")
    table = np.array([[float(v) for v in row.split(",")] for row in lines[1:]])
    np.testing.assert_array_equal(table[:, 12:15], z["block_pos"])
    np.testing.assert_array_equal(table[:, 1:4], z["mocap_pos"])
    np.testing.assert_allclose(table[:, 22], a0 + yaw, atol=1e-15)
    # the CLI: --format csv, and a suffix that contradicts it
    out = tmp_path / "cli_plan"
    assert main(["mujoco", "export", str(SCENE_TOML), "--format", "csv", "--out", str(out),
                 "--elements", "2", "2", "1"]) == 0
    assert (tmp_path / "cli_plan.csv").read_text().startswith("time,mocap_x,")
    assert main(["mujoco", "export", str(SCENE_TOML), "--format", "csv", "--out", str(tmp_path / "p.npz")]) == 2
    assert "--format csv" in capsys.readouterr().err


def _base_table() -> dict:
    """A scenario table agreeing with the MJCF (material from its numerics)."""
    return {"block": {"size": [0.02, 0.02, HEIGHT], "elements": list(COARSE), "quadrature": 2},
            "material": {"young": 210e9, "poisson": 0.3},
            "friction": {"mu_x": 0.3, "mu_y": 0.05}, "solver": {"local_method": "newton"}}


# ------------------------------------------------------------- forces into MuJoCo


def test_cosimulation_writes_the_fe_forces_into_userdata_and_the_reaction_on_the_gripper(tmp_path):
    path = yawed_scene(tmp_path)
    scene = scene_from_mjcf(path)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    fe = scene.scenario.model(elements=(3, 3, 1), quadrature=2)
    coupler = CoSimulation(m, d, scene, "gripper", 0.01, fe)
    bid, gid = m.body("block").id, m.body("gripper").id
    R0 = rz(math.radians(YAW0_DEG))
    lower = fe.mesh.lower
    n_sub = 10
    for inc in (PRESS, PUSH, PUSH):
        world = R0 @ [inc.dx, inc.dy, inc.dz]
        start = d.mocap_pos[0].copy()
        rep = None
        for j in range(1, n_sub + 1):
            d.mocap_pos[0] = start + world * j / n_sub
            mujoco.mj_step(m, d)
            rep = coupler.update() or rep
        assert rep is not None and rep.converged
        # what the FE step says, carried into the world by the scene's yaw (by hand here)
        gripper = R0 @ rep.upper_force
        contact = R0 @ rep.reaction_world.sum(axis=0)
        points = np.array([X0, Y0, 0.0]) + (fe.mesh.nodes[lower] + rep.displacement[lower]) @ R0.T
        moment = np.cross(points - d.xipos[bid], rep.reaction_world @ R0.T).sum(axis=0)  # about MuJoCo's CoM
        # the gripper's moment balances the contact's and the self-weight's (MJCF density)
        nodes = np.array([X0, Y0, 0.0]) + (fe.mesh.nodes + rep.displacement) @ R0.T
        weight = fe.body_force.reshape(-1, 3) @ R0.T
        assert weight[:, 2].sum() == pytest.approx(-7850 * 9.81 * 0.02 * 0.02 * 0.01, rel=1e-12)
        grip_moment = -(np.cross(points - d.xipos[gid], rep.reaction_world @ R0.T).sum(axis=0)
                        + np.cross(nodes - d.xipos[gid], weight).sum(axis=0))
        for written, expected in ((d.userdata[0:3], gripper), (d.userdata[3:6], contact),
                                  (d.userdata[6:9], moment), (d.xfrc_applied[gid, :3], -gripper),
                                  (d.xfrc_applied[gid, 3:], -grip_moment)):
            np.testing.assert_allclose(written, expected, rtol=0, atol=FORCE_REL * np.linalg.norm(expected))
        assert not d.xfrc_applied[bid].any()  # the block is kinematic: no partial wrench on it
        assert contact[2] == pytest.approx(rep.normal_force, rel=1e-12) and contact[2] > 0  # the floor pushes up
    # between control periods nothing is recomputed and nothing moves the block
    pos = d.qpos[:7].copy()
    mujoco.mj_step(m, d)
    assert coupler.update() is None
    assert np.abs(d.qpos[:7] - pos).max() < 1e-15
    np.testing.assert_allclose(d.xfrc_applied[gid, :3], -gripper, rtol=0, atol=FORCE_REL * np.linalg.norm(gripper))


# ------------------------------------------------- co-simulation: world frame, rrd


def test_cosimulation_record_is_in_the_world_frame_and_the_recording_has_sim_time(tmp_path):
    from rerun.chunk import RrdReader

    path = yawed_scene(tmp_path)
    scene = scene_from_mjcf(path)
    fe = scene.scenario.model(elements=COARSE, quadrature=2)
    record = run_cosimulation(scene, [PRESS, PUSH, PUSH], "gripper", 0.02, fe, rrd_path=tmp_path / "cosim.rrd")
    disp, yaw = _fe_lower_poses(fe, [PRESS, PUSH, PUSH])
    R0 = rz(math.radians(YAW0_DEG))
    for k, p in enumerate(record.to_dict()["periods"], start=1):
        expected = np.array([X0, Y0, 0.0]) + R0 @ disp[k]
        np.testing.assert_allclose(p["lower_centre"], expected, atol=POSE_TOL)
        np.testing.assert_allclose(p["mujoco_lower_centre"], expected, atol=POSE_TOL)
        assert p["lower_yaw_deg"] == pytest.approx(YAW0_DEG + math.degrees(yaw[k]), abs=1e-9)
        assert p["mujoco_yaw_deg"] == pytest.approx(p["lower_yaw_deg"], abs=1e-9)
    json.dumps(record.to_dict(), default=lambda a: a.tolist())  # JSON-ready
    # read back with rerun's own reader
    chunks = RrdReader(tmp_path / "cosim.rrd").stream().to_chunks()
    times, boxes = set(), []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/run/step":
            assert "sim_time" in batch.schema.names
            times.update(batch.column("sim_time").to_pylist())
        if chunk.entity_path == "/world/mujoco/block_geom":
            boxes.extend(batch.column("Boxes3D:centers").to_pylist())
    seconds = sorted(t.total_seconds() if hasattr(t, "total_seconds") else t * 1e-9 for t in times)
    assert seconds == pytest.approx([0.02, 0.04, 0.06], abs=1e-9)
    assert len(boxes) == 3
    np.testing.assert_allclose(np.array(boxes[-1][0]), np.array([X0, Y0, HEIGHT / 2]) + R0 @ disp[-1], atol=1e-6)


# --------------------------------------------------------- planner, world frame


def test_plan_frame_needs_the_world_pose_and_converts_the_target():
    data = {**_base_table(), "name": "w", "load": [{"dz": -0.1e-3}],
            "plan": {"x": X0 + 1e-3, "y": Y0, "yaw_deg": YAW0_DEG + 1.0, "max_dtheta_deg": 1.0, "steps": 4,
                     "max_step": 4e-4, "frame": "world"}}
    with pytest.raises(InputError, match="frame = 'world' needs"):
        parse_plan(parse_scenario(data))
    origin = (X0, Y0, math.radians(YAW0_DEG))
    spec = parse_plan(parse_scenario(data), world_origin=origin)
    a0 = math.radians(YAW0_DEG)
    assert spec.target == pytest.approx((1e-3 * math.cos(a0), -1e-3 * math.sin(a0), math.radians(1.0)), abs=1e-15)
    assert parse_plan(parse_scenario({**data, "plan": spec.to_table()}), world_origin=origin) == spec
    assert spec.to_dict()["frame"] == "world" and spec.to_dict()["world"]["x"] == X0 + 1e-3
    with pytest.raises(InputError, match="plan.frame must be one of"):
        parse_plan(parse_scenario({**data, "plan": {**data["plan"], "frame": "robot"}}), world_origin=origin)


def test_plan_to_a_world_target_of_a_yawed_block_and_reach_it_in_mujoco(tmp_path):
    path = yawed_scene(tmp_path)
    target = (X0 + 0.6e-3, Y0 + 0.8e-3)          # 1 mm from rest, along world (0.6, 0.8)
    tolerance = 5e-6
    lines = [
        'name = "plan_world"', "[block]", "size = [0.02, 0.02, 0.01]", "elements = [4, 4, 2]", "quadrature = 2",
        "[material]", "young = 210e9", "poisson = 0.3", "[friction]", "mu_x = 0.3", "mu_y = 0.05",
        "[[load]]", "dz = -0.1e-3", "[solver]", 'local_method = "newton"',
        "[plan]", f"x = {target[0]!r}", f"y = {target[1]!r}", "steps = 4", "max_step = 0.4e-3",
        f"tolerance = {tolerance!r}", "planning_elements = [3, 3, 1]", "planning_quadrature = 2",
        'frame = "world"', "[mujoco]", f'scene = "{path.name}"', "control_period = 0.01",
    ]
    toml = tmp_path / "plan_world.toml"
    toml.write_text("\n".join(lines) + "\n")
    assert main(["plan", str(toml), "--out", str(tmp_path / "plan"), "--quiet", "--no-recording"]) == 0
    doc = json.loads((tmp_path / "plan" / "plan.json").read_text())
    assert doc["plan"]["frame"] == "world" and doc["plan"]["world"]["x"] == target[0]
    # the block-frame target is the world displacement turned by -3 deg
    a0 = math.radians(YAW0_DEG)
    block = rz(-a0) @ [0.6e-3, 0.8e-3, 0.0]
    assert (doc["plan"]["x"], doc["plan"]["y"]) == pytest.approx(tuple(block[:2]), abs=1e-15)
    # the verified final pose, carried into the world here, is within tolerance of the target
    x, y, _ = doc["poses"]["verified"][-1]
    world = np.array([X0, Y0]) + (rz(a0) @ [x, y, 0.0])[:2]
    assert np.hypot(*(world - target)) <= tolerance
    assert doc["world"]["verified_final"][:2] == pytest.approx(list(world), abs=1e-15)
    # and MuJoCo, running the plan's commands through the co-simulation, shows the block there
    out = tmp_path / "cosim"
    assert main(["mujoco", "cosim", str(toml), "--commands", str(tmp_path / "plan" / "plan.json"),
                 "--out", str(out), "--no-rerun"]) == 0
    last = json.loads((out / "cosim.json").read_text())["periods"][-1]
    assert np.hypot(*(np.array(last["mujoco_lower_centre"][:2]) - target)) <= tolerance
