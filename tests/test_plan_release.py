"""Planning to the pose at rest after the release (issue 19), on a coarse rubber block:
``target_state = "rest"`` with an open and a lifting gripper, plan.json's loaded and
rest poses, and ``simulate --commands plan.json`` reproducing the verified rest pose."""

import json

import pytest

from pushplan.cli import EXIT_BAD_INPUT, main

REPRODUCE_ATOL = 1e-12  # m: simulate --commands plan.json re-runs the verified rollout (same steps)

PLAN = """
name = "plan_rest"
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
[release]
mode = "open"
steps = 4
[plan]
x = 3e-3
y = 1e-3
yaw_deg = 5.0
steps = 5
max_step = 1.2e-3
max_dtheta_deg = 2.0
tolerance = 1e-5
planning_elements = [4, 3, 2]
planning_quadrature = 2
"""


def plan(tmp_path, text, name="p"):
    (tmp_path / f"{name}.toml").write_text(text)
    out = tmp_path / f"plan_{name}"
    rc = main(["plan", str(tmp_path / f"{name}.toml"), "--out", str(out), "--quiet", "--no-recording"])
    return rc, json.loads((out / "plan.json").read_text())


@pytest.mark.xdist_group("plan_release")
def test_plan_to_rest_with_open_release_and_reproduce(tmp_path):
    rc, doc = plan(tmp_path, PLAN)
    assert rc == 0 and doc["status"] == "converged"
    assert doc["plan"]["target_state"] == "rest" and doc["release"]["mode"] == "open"
    assert doc["release"]["gripper_friction"] == "bonded"
    rest, naive_rest = doc["final_poses"]["rest"], doc["naive"]["final_poses"]["rest"]
    assert rest["error"]["position"] <= 1e-5 and rest["error"] == doc["final_error"]
    assert naive_rest["error"] == doc["naive"]["final_error"]
    assert naive_rest["error"]["position"] > 10 * rest["error"]["position"]  # the naive error at rest, beside it
    assert doc["final_poses"]["loaded"] is not None and doc["naive"]["final_poses"]["loaded"] is not None
    out = tmp_path / "sim"
    assert main(["simulate", str(tmp_path / "p.toml"), "--commands", str(tmp_path / "plan_p" / "plan.json"),
                 "--out", str(out), "--quiet", "--no-recording"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["rest"]["lower_centroid"][:2] == pytest.approx(rest["pose"][:2], abs=REPRODUCE_ATOL)
    assert summary["rest"]["lower_yaw_deg"] == pytest.approx(rest["pose"][2], abs=1e-9)


@pytest.mark.xdist_group("plan_release")
def test_plan_with_lift_is_the_commanded_pose(tmp_path):
    text = PLAN.replace('mode = "open"', 'mode = "lift"').replace("density = 1000.0", "density = 0.0")
    rc, doc = plan(tmp_path, text)
    assert rc == 0 and doc["status"] == "converged"
    assert doc["reduced_model"]["springback"]["position"] == pytest.approx(1.0, abs=1e-6)
    # calibration (push, rotation) and one rollout on the planning mesh; one rollout and the naive one on the
    # verification mesh
    assert doc["solver"]["fe_rollouts"] == {"planning": 3, "verification": 2}
    assert doc["naive"]["final_poses"]["rest"]["error"]["position"] <= 1e-8


def test_rest_target_needs_a_release(tmp_path, capsys):
    text = PLAN.replace('[release]\nmode = "open"\nsteps = 4\n', "").replace("[plan]\n",
                                                                             '[plan]\ntarget_state = "rest"\n')
    (tmp_path / "p.toml").write_text(text)
    assert main(["plan", str(tmp_path / "p.toml"), "--out", str(tmp_path / "out"), "--quiet"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plan.target_state" in err[0]
    assert not (tmp_path / "out").exists()
