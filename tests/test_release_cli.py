"""The release in pushplan (issues 19, 28): the scenario tables, their validation
(the removed open release refused, naming the key), and ``simulate``'s rest pose in
summary.json; coarse rubber block."""

import json
import math

import pytest

from pushplan.cli import EXIT_BAD_INPUT, EXIT_SOLVER_FAILURE, main
from pushplan.config import parse_scenario
from pushplan.config.files import read_toml

REST_FORCE_RTOL = 1e-8  # issue: in-plane contact forces at rest <= 1e-8 of the weight
REST_POSE_RTOL = 1e-6  # issue: lift rest pose = commanded motion to 1e-6 of the lag
REST_KEYS = {"mode", "lower_centroid", "lower_yaw_deg", "upper_centroid", "normal_force", "tangential_force",
             "strain_energy", "status", "step", "reason", "pad_force", "further_motion", "gripper_friction"}

RUBBER = """
name = "rubber"
[block]
size = [0.04, 0.03, 0.02]
elements = [4, 3, 2]
quadrature = 2
[material]
young = 2e6
poisson = 0.45
density = 1000.0
[friction]
mu_x = 0.6
mu_y = 0.2
angle_deg = 20.0
[[load]]
dz = -4e-4
[[load]]
dx = 1e-3
dy = 5e-4
dtheta_deg = 2.0
repeat = 3
[release]
mode = "lift"
steps = 4
"""


def simulate(tmp_path, text, name="s"):
    (tmp_path / f"{name}.toml").write_text(text)
    out = tmp_path / f"out_{name}"
    assert main(["simulate", str(tmp_path / f"{name}.toml"), "--out", str(out), "--quiet", "--no-recording"]) == 0
    return json.loads((out / "summary.json").read_text())


def test_scenario_tables_round_trip(tmp_path):
    text = RUBBER.replace("steps = 4", "steps = 4\nheight = 1e-3\naway = [2e-3, -1e-3]") + \
        "[gripper]\nstiffness_xy = 4e4\nstiffness_yaw = 5.0\n"
    (tmp_path / "s.toml").write_text(text)
    s = parse_scenario(read_toml(tmp_path / "s.toml"))
    assert s.density == 1000.0 and s.release.mode == "lift" and s.release.steps == 4
    assert s.release.away == (2e-3, -1e-3) and s.release.height == 1e-3
    assert s.gripper.stiffness_xy == 4e4
    assert parse_scenario(s.to_dict()) == s
    plain = parse_scenario(read_toml(tmp_path / "s.toml") | {"release": {"mode": "lift"}})
    assert plain.release.steps == 16 and parse_scenario(plain.to_dict()) == plain


BAD = {
    "open (removed)": (('mode = "lift"', 'mode = "open"'), "release.mode"),
    "away not a pair": (("steps = 4", "steps = 4\naway = [1e-3]"), "release.away"),
    "away not a number": (("steps = 4", "steps = 4\naway = [1e-3, \"x\"]"), "release.away[1]"),
    "error_tol (removed by issue 39)": (("steps = 4", "steps = 4\nerror_tol = 1e-2"), "release.error_tol"),
    "error_tol tiny (issue 43)": (("steps = 4", "steps = 4\nerror_tol = 1e-9"), "release.error_tol"),
    "steps past the bound": (("steps = 4", "steps = 1000000"), "release.steps"),
    "negative density": (("density = 1000.0", "density = -1.0"), "material.density"),
    "negative stiffness": (("[release]", "[gripper]\nstiffness_xy = -1.0\nstiffness_yaw = 1.0\n[release]"),
                           "gripper.stiffness_xy"),
    "zero steps": (("steps = 4", "steps = 0"), "release.steps"),
    "unknown mode": (('mode = "lift"', 'mode = "drop"'), "release.mode"),
    "release without a press": (("dz = -4e-4", "dz = 0.0"), "release.mode"),
    "negative lift height": (('mode = "lift"', 'mode = "lift"\nheight = -1e-3'), "release.height"),
    "negative pad friction": (("[release]", "[gripper]\nfriction = -0.1\n[release]"), "gripper.friction"),
    "pad friction word": (("[release]", "[gripper]\nfriction = \"sticky\"\n[release]"), "gripper.friction"),
    "negative pad mu_y": (("[release]", "[gripper.friction]\nmu_x = 1.0\nmu_y = -1.0\n[release]"),
                          "gripper.friction.mu_y"),
    "frictional pad, no weight": (("density = 1000.0", "density = 0.0\n[gripper]\nfriction = 1.0"),
                                  "gripper.friction"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_release_input_exits_2_naming_the_key(name, tmp_path, capsys):
    (old, new), key = BAD[name]
    assert old in RUBBER
    (tmp_path / "s.toml").write_text(RUBBER.replace(old, new))
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    rc = main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet", "--no-recording"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT
    assert len(err) == 1 and err[0].startswith("pushplan: error: ") and key in err[0], err
    assert not (tmp_path / "out").exists()
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_a_compliant_gripper_with_a_frictional_pad_settles(tmp_path):
    """fe_contact solves a compliant gripper's plate with a frictional pad (issue 39):
    a scenario with both is simulated, not refused as bad input; the released block
    settles with the floor carrying its weight and the plate's springs loaded during
    the push."""
    text = RUBBER.replace("[release]", "[gripper]\nfriction = 0.9\nstiffness_xy = 4e4\nstiffness_yaw = 5.0\n"
                                       "[release]")
    summary = simulate(tmp_path, text)
    s = parse_scenario(summary["scenario"])
    assert s.gripper.stiffness_xy == 4e4 and s.pad is not None and parse_scenario(s.to_dict()) == s
    weight = 1000.0 * 9.81 * 0.04 * 0.03 * 0.02
    rest = summary["rest"]
    assert rest["status"] == "settled" and rest["normal_force"] == pytest.approx(weight, rel=1e-9)
    assert rest["pad_force"] <= 1e-9 * weight


def test_release_messages_name_only_what_is_allowed(tmp_path, capsys):
    """An unknown [release] key lists the allowed keys without the removed error_tol."""
    (tmp_path / "s.toml").write_text(RUBBER.replace("steps = 4", "steps = 4\nstepz = 3"))
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "release.stepz" in err and "allowed: away, height, mode, steps)" in err and "error_tol" not in err


def test_a_command_file_that_opens_the_gripper_exits_2(tmp_path, capsys):
    """The open release's ``"open"`` command steps are refused, naming the key."""
    (tmp_path / "s.toml").write_text(RUBBER)
    (tmp_path / "c.json").write_text(json.dumps({"commands": [{"dz": -4e-4}, {"open": 1.0}]}))
    rc = main(["simulate", str(tmp_path / "s.toml"), "--commands", str(tmp_path / "c.json"),
               "--out", str(tmp_path / "out"), "--quiet", "--no-recording"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT and len(err) == 1 and "commands[1].open" in err[0] and "lift" in err[0], err


def test_simulate_lift_rests_under_the_commanded_upper_face(tmp_path):
    text = RUBBER.replace("density = 1000.0", "density = 0.0")
    summary = simulate(tmp_path, text)
    rest, loaded = summary["rest"], summary["steps"][3]
    lag = math.hypot(*loaded["lag"])
    assert math.dist(rest["lower_centroid"][:2], [3e-3, 1.5e-3]) <= REST_POSE_RTOL * lag
    assert rest["lower_yaw_deg"] == pytest.approx(6.0, abs=REST_POSE_RTOL * lag / 0.04 * 180 / math.pi)
    press_work = summary["steps"][0]["normal_force"] * 4e-4  # an energy scale of the loaded block, J
    assert rest["strain_energy"] <= 1e-9 * press_work


def test_a_block_that_does_not_settle_exits_3(tmp_path, capsys, monkeypatch):
    """Rest is judged, not assumed: with a settling criterion no release can
    meet (one more step must move nothing at all, to the last bit), simulate
    says why in one line and exits 3; summary.json says not_settled."""
    import fe_contact.stepping.release as release_module

    monkeypatch.setattr(release_module, "SETTLE_MOTION", -1.0)
    (tmp_path / "s.toml").write_text(RUBBER)
    out = tmp_path / "out"
    rc = main(["simulate", str(tmp_path / "s.toml"), "--out", str(out), "--quiet", "--no-recording"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_SOLVER_FAILURE
    assert len(err) == 1 and "did not settle" in err[0] and "one more step moves" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    rest = summary["rest"]
    assert rest["status"] == "not_settled" and "one more step moves" in rest["reason"]
    # issue 43: the file says what the exit status says, never "completed" beside exit 3
    assert summary["status"] == "failed" and "did not settle" in summary["failure"]["message"]


def test_a_frictional_pad_round_trips_and_its_rest_says_so(tmp_path):
    """``[gripper] friction``: the pad's friction is in the scenario, and the rest
    pose in summary.json says which gripper friction it assumes."""
    text = RUBBER.replace("repeat = 3", "repeat = 1") + \
        "[gripper.friction]\nmu_x = 0.9\nmu_y = 0.3\nangle_deg = 10.0\n"
    (tmp_path / "s.toml").write_text(text)
    s = parse_scenario(read_toml(tmp_path / "s.toml"))
    assert s.pad.mu_x == 0.9 and s.gripper is None and parse_scenario(s.to_dict()) == s
    summary = simulate(tmp_path, text)
    rest = summary["rest"]
    assert rest["status"] == "settled" and rest["pad_force"] <= 1e-9 * 1000.0 * 9.81 * 0.04 * 0.03 * 0.02
    assert rest["gripper_friction"] == pytest.approx({"mu_x": 0.9, "mu_y": 0.3, "angle_deg": 10.0})
    assert summary["scenario"]["gripper"]["friction"] == rest["gripper_friction"]
    bonded = simulate(tmp_path, RUBBER, name="b")
    assert bonded["rest"]["gripper_friction"] == "bonded"
