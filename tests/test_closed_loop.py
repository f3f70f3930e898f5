"""Closed loop (issue 20): re-planning from observations (``pushplan plan --from``) and
the loop on a truth model whose friction is 30 % off the model's
(``pushplan closed-loop``).  Coarse meshes (4 x 4 x 2) keep it to seconds."""

import json
import math

import numpy as np
import pytest

from pushplan.cli import EXIT_BAD_INPUT, main

MODEL = """
name = "cl_model"
[block]
size = [0.020, 0.020, 0.010]
elements = [4, 4, 2]
quadrature = 2
[material]
young = 210.0e9
poisson = 0.3
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = 25.0
[[load]]
dz = -0.1e-3
[solver]
local_method = "newton"
"""
PLAN = """
[plan]
x = 0.6e-3
y = 0.3e-3
steps = 4
max_step = 0.25e-3
tolerance = 0.3e-6
planning_elements = [4, 4, 2]
planning_quadrature = 2
"""
TARGET = (0.6e-3, 0.3e-3)
TOLERANCE = 0.3e-6


def write(tmp_path, name, mu_x, mu_y, plan=True):
    path = tmp_path / name
    path.write_text(MODEL.format(mu_x=mu_x, mu_y=mu_y) + (PLAN if plan else ""))
    return path


def test_plan_from_observations_reaches_the_target_from_the_measured_state(tmp_path):
    model = write(tmp_path, "model.toml", 0.3, 0.15)
    assert main(["plan", str(model), "--out", str(tmp_path / "p0"), "--quiet", "--no-recording"]) == 0
    first = json.loads((tmp_path / "p0" / "plan.json").read_text())
    assert first["pose_units"] == ["m", "m", "deg"]  # the file's yaw is in degrees, the service's in radians
    # execute the press and two planned pushes, observe
    executed = {"commands": first["commands"][:3]}
    (tmp_path / "executed.json").write_text(json.dumps(executed))
    assert main(["simulate", str(model), "--commands", str(tmp_path / "executed.json"), "--out",
                 str(tmp_path / "s"), "--quiet", "--no-recording", "--observations", str(tmp_path / "obs.csv")]) == 0
    assert main(["plan", str(model), "--from", str(tmp_path / "obs.csv"), "--out", str(tmp_path / "p1"),
                 "--quiet", "--no-recording"]) == 0
    doc = json.loads((tmp_path / "p1" / "plan.json").read_text())
    assert doc["from"]["executed_pushes"] == 2 and doc["plan"]["steps"] == 2
    assert len(doc["commands"]) == 5 and doc["commands"][:3] == first["commands"][:3]
    # the re-planned sequence, run from rest, ends at the absolute target
    assert main(["simulate", str(model), "--commands", str(tmp_path / "p1" / "plan.json"), "--out",
                 str(tmp_path / "s2"), "--quiet", "--no-recording"]) == 0
    last = json.loads((tmp_path / "s2" / "summary.json").read_text())["steps"][-1]["lower_centroid"]
    assert math.hypot(last[0] - TARGET[0], last[1] - TARGET[1]) <= TOLERANCE


def test_plan_from_refuses_observations_without_the_pose(tmp_path, capsys):
    model = write(tmp_path, "model.toml", 0.3, 0.15)
    (tmp_path / "obs.csv").write_text("dx,dy,dz,dtheta_deg,force_x\n0,0,-0.0001,0,0\n1e-4,0,0,0,-5\n")
    code = main(["plan", str(model), "--from", str(tmp_path / "obs.csv"), "--out", str(tmp_path / "p"), "--quiet"])
    assert code == EXIT_BAD_INPUT
    assert "missing column lower_x" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()


@pytest.mark.parametrize("identify", [False, True])
def test_closed_loop_ends_within_tolerance_the_open_loop_misses(tmp_path, identify):
    model = write(tmp_path, "model.toml", 0.3, 0.15)
    truth = write(tmp_path, "truth.toml", 0.39, 0.195, plan=False)  # friction 30 % above the model's
    code = main(["closed-loop", str(model), "--truth", str(truth), "--out", str(tmp_path / "cl"), "--quiet",
                 *(["--identify"] if identify else []), *([] if identify else ["--no-recording"])])
    assert code == 0
    doc = json.loads((tmp_path / "cl" / "closed_loop.json").read_text())
    assert doc["pose_units"] == ["m", "m", "deg"]  # the file's yaw is in degrees, the service's in radians
    closed, open_ = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    assert closed["within_tolerance"] and closed["position"] <= TOLERANCE
    assert open_["position"] >= 10 * closed["position"]
    assert len(doc["iterations"]) == 4
    # each plan behind a push ends at the target (on the model it was planned with)
    for it in doc["iterations"]:
        end = it["planned_path"][-1]
        assert math.hypot(end[0] - TARGET[0], end[1] - TARGET[1]) <= TOLERANCE
        assert len(it["planned_path"]) == 4 - it["step"] + 2
    # the loop ends where its last observation says
    x, y, _ = doc["iterations"][-1]["observed_pose"]
    assert math.hypot(x - TARGET[0], y - TARGET[1]) == pytest.approx(closed["position"], rel=1e-12)
    assert (tmp_path / "cl" / "recording.rrd").exists() == identify
    est = doc["final_estimates"]
    if not identify:
        assert est is None and doc["iterations"][-1]["planned_with"]["mu_x"] == 0.3
        return
    # the plan pushes near t_x: mu_x is identified, mu_y not (kept at the model's value, flagged)
    assert not est["mu_y"]["identifiable"]
    assert est["mu_x"]["identifiable"] and abs(est["mu_x"]["estimate"] - 0.39) <= 0.03 * 0.39
    assert doc["iterations"][-1]["planned_with"]["mu_x"] == pytest.approx(0.39, rel=0.03)


YAW_MODEL = """
name = "yaw_model"
[block]
size = [0.020, 0.020, 0.010]
elements = [4, 4, 2]
quadrature = 2
[material]
young = {young}
poisson = 0.45
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = 0.0
[[load]]
dz = -0.3e-3
[solver]
local_method = "newton"
"""
YAW_PLAN = """
[plan]
x = 2.0e-3
y = 1.0e-3
yaw_deg = 8.0
steps = 6
max_step = 0.8e-3
max_dtheta_deg = 3.0
tolerance = 4.0e-6
yaw_tolerance_deg = 0.1
planning_elements = [4, 4, 2]
planning_quadrature = 2
"""


def test_calibration_never_returns_a_negative_compliance():
    import numpy as np

    from pushplan.config import parse_scenario
    from pushplan.planning.reduced_model import calibrate, elastic_estimate
    from pushplan.planning.rollouts import FeRollouts
    import tomllib

    from pushplan.config.commands import planar_commands
    from pushplan.config.plan import press_commands

    sc = parse_scenario(tomllib.loads(YAW_MODEL.format(young=5e6, mu_x=0.8, mu_y=0.3)))
    model = sc.model()
    fe = FeRollouts(model, press_commands(sc), "t")
    push = fe.rollout(np.tile([0.3e-3, 0.0, 0.0], (2, 1)))
    # a twist from a loaded, twisted state (what a re-plan used to calibrate on): its yaw is
    # absolute, its lag relative; the ratio is negative and the elastic estimate stands in
    loaded = FeRollouts(model, press_commands(sc), "t", after=planar_commands(np.array([[0.5e-3, 0.2e-3, 0.026]] * 3)))
    twist = loaded.rollout(np.tile([0.0, 0.0, 0.05], (6, 1)))
    est = elastic_estimate(model, push.reports[-1].normal_force)
    p = calibrate(model, push.reports, twist.reports)
    assert p.compliance > 0 and p.torsion_compliance > 0 and p.max_torque > 0
    assert p.torsion_compliance == est["torsion_compliance"]
    # from rest the rollout calibrates, near the elastic estimate (within 20 %)
    rest = calibrate(model, push.reports, fe.rollout(np.tile([0.0, 0.0, 0.05], (2, 1))).reports)
    assert rest.torsion_compliance != est["torsion_compliance"]
    assert rest.torsion_compliance == pytest.approx(est["torsion_compliance"], rel=0.2)


def _loop(tmp_path, model_text, truth_text):
    (tmp_path / "m.toml").write_text(model_text)
    (tmp_path / "t.toml").write_text(truth_text)
    code = main(["closed-loop", str(tmp_path / "m.toml"), "--truth", str(tmp_path / "t.toml"), "--out",
                 str(tmp_path / "cl"), "--quiet", "--no-recording", "--identify"])
    return code, json.loads((tmp_path / "cl" / "closed_loop.json").read_text())


def test_closed_loop_reaches_a_yaw_target_on_a_finer_stiffer_truth(tmp_path):
    # issue 29 acceptance: friction 30 % and Young's modulus 20 % off, the truth on a finer mesh;
    # its re-plans from loaded, twisted states used to calibrate a negative torsion compliance (exit 2)
    model = YAW_MODEL.format(young=5e6, mu_x=0.8, mu_y=0.3) + YAW_PLAN
    truth = YAW_MODEL.format(young=6e6, mu_x=1.04, mu_y=0.39).replace("[4, 4, 2]", "[6, 6, 3]")
    code, doc = _loop(tmp_path, model, truth)
    closed, open_ = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    assert code == 0 and closed["within_tolerance"], closed
    assert closed["position"] <= 4e-6 and closed["yaw_deg"] <= 0.1
    assert open_["position"] >= 5 * closed["position"] and open_["yaw_deg"] >= 5 * closed["yaw_deg"]
    assert doc["scored_on"] == "loaded pose"


def test_closed_loop_reaches_a_rest_target_scored_on_the_truths_release(tmp_path):
    from test_plan_release import PLAN

    # a frictional pad (the physical release by load control); the truth on the model's mesh. With the truth on 4 x 3 x 2 the loop ends 779 um off (open
    # loop 821 um; 226 um before closed_loop.modifier): the truth springs back 0.51 of its lag at the
    # release (pad 0.8 on a 0.78 floor), the model 0.93 (pad 0.8 on 0.6), and the loop does not observe
    # the release
    model = PLAN
    truth = (model.split("[plan]")[0].replace("mu_x = 0.6", "mu_x = 0.78").replace("mu_y = 0.2", "mu_y = 0.26")
             .replace("young = 2e6", "young = 2.4e6"))
    code, doc = _loop(tmp_path, model, truth)
    closed, open_ = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    assert doc["scored_on"] == "rest pose after the truth's release"
    assert code == 0 and closed["within_tolerance"] and closed["position"] <= 1e-5, closed
    assert open_["position"] >= 5 * closed["position"]
    # the score is the rest pose, not the last loaded one (the release moves the block)
    loaded = doc["iterations"][-1]["observed_pose"]
    rest = doc["closed_loop"]["final_pose"]
    assert math.hypot(rest[0] - loaded[0], rest[1] - loaded[1]) > 100 * closed["position"]


def test_an_input_error_inside_the_loop_is_a_bug_not_bad_input(tmp_path, monkeypatch):
    from pushplan.identify import closed_loop as loop
    from pushplan.errors import InputError

    def broken(*args, **kwargs):
        raise InputError("compliance must be > 0, got -1")

    monkeypatch.setattr(loop, "replan", broken)
    model = write(tmp_path, "model.toml", 0.3, 0.15)
    truth = write(tmp_path, "truth.toml", 0.39, 0.195, plan=False)
    with pytest.raises(loop.LoopError, match="closed loop step 2: compliance must be > 0"):
        main(["closed-loop", str(model), "--truth", str(truth), "--out", str(tmp_path / "cl"), "--quiet",
              "--no-recording"])


def test_the_warm_closed_loop_ends_as_the_cold_one(tmp_path):
    """Issue 32: re-planning warm (one PlanSession on the planning mesh) or cold (each
    re-plan from the press on both meshes; here the same 4 x 4 x 2 mesh) ends at the same
    pose to within the tolerance, both within it, and no worse than the open loop."""
    import tomllib

    import numpy as np

    from pushplan.config import parse_scenario
    from pushplan.config.plan import parse_plan
    from pushplan.identify.closed_loop import closed_loop

    model = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.3, mu_y=0.15) + PLAN))
    truth = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.39, mu_y=0.195)))
    spec = parse_plan(model)
    warm, cold = (closed_loop(model, truth, spec, warm=w) for w in (True, False))
    a, b = (r.final_pose[:2] for r in (warm, cold))
    assert np.hypot(*(a - b)) <= TOLERANCE
    assert [it.plan_status for it in warm.iterations] == [it.plan_status for it in cold.iterations]
    for r in (warm, cold):
        for it in r.iterations:  # issue 43: each re-plan says why it has its status
            assert it.plan_message, it
            assert it.plan_status != "infeasible" or "beyond reach" in it.plan_message, it
        assert r.within_tolerance and r.to_dict()["closed_loop"]["final_error"]["within_tolerance"]
        assert r.position_error <= r.open_position_error


LIFT_BLOCK = """
[block]
size = [0.04, 0.03, 0.02]
elements = {elements}
quadrature = 2
[material]
young = {young}
poisson = 0.45
density = 1000.0
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = {angle}
[[load]]
dz = -4e-4
[release]
mode = "lift"
steps = 4
"""
LIFT_PLAN = """
[plan]
x = 3e-3
y = 1e-3
steps = 4
max_step = 1.2e-3
tolerance = 3e-5
target_state = "rest"
planning_elements = [4, 3, 2]
planning_quadrature = 2
"""


@pytest.mark.parametrize("identify", [False, True])
def test_a_rest_target_after_a_bonded_lift_ends_no_worse_than_the_open_loop(tmp_path, identify):
    # a bonded pad's lift leaves the block at the commanded pose whatever its lag, so the
    # open loop is exact; the loaded discrepancy the loop observes (the truth is stiffer,
    # finer, with other friction) must not be carried into the rest target: before
    # closed_loop.modifier the loop ended 141 um away (71 um with --identify), tolerance 30 um
    (tmp_path / "truth.toml").write_text('name = "truth"' + LIFT_BLOCK.format(
        elements=[6, 4, 3], young=2.4e6, mu_x=0.78, mu_y=0.26, angle=20.0))
    (tmp_path / "model.toml").write_text('name = "model"' + LIFT_BLOCK.format(
        elements=[4, 3, 2], young=2.2e6, mu_x=0.75, mu_y=0.3, angle=15.0) + LIFT_PLAN)
    args = ["closed-loop", str(tmp_path / "model.toml"), "--truth", str(tmp_path / "truth.toml"), "--force",
            "--out", str(tmp_path / "cl"), "--quiet", "--no-recording"] + (["--identify"] if identify else [])
    assert main(args) == 0
    doc = json.loads((tmp_path / "cl" / "closed_loop.json").read_text())
    closed, opened = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    assert opened["position"] < 1e-9  # the lift's rest is the commanded pose
    assert closed["within_tolerance"], closed
    assert closed["position"] <= (1e-9 if not identify else 0.5 * 3e-5), closed


def test_the_rest_modifier_between_its_two_bounds():
    from types import SimpleNamespace

    from pushplan.identify.closed_loop import modifier

    rest, loaded = SimpleNamespace(target_state="rest"), SimpleNamespace(target_state="loaded")
    bias, drift = np.array([1.0, 2.0, 0.1]), np.array([5.0, -3.0, 0.2])
    # a pad that lets the block spring back fully (the bonded lift): the discrepancy comes out
    assert np.allclose(modifier(rest, bias, drift, np.ones(3)), -drift)
    # none springs back: the last push's error persists, as for a loaded target
    assert np.allclose(modifier(rest, bias, drift, np.zeros(3)), bias)
    assert np.allclose(modifier(rest, bias, drift, np.full(3, 0.25)), 0.75 * bias - 0.25 * drift)
    assert np.allclose(modifier(loaded, bias, drift, np.ones(3)), bias)


COARSE_PLAN_BLOCK = """
[block]
size = [0.036, 0.024, 0.016]
elements = {elements}
quadrature = 2
[material]
young = {young}
poisson = 0.42
density = 1150.0
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = {angle}
[[load]]
dz = -0.3e-3
[release]
mode = "lift"
"""
COARSE_REST_PLAN = """
[plan]
x = 1.2e-3
y = 0.7e-3
steps = 3
max_step = 0.6e-3
tolerance = 2.0e-5
planning_elements = [3, 2, 2]
planning_quadrature = 2
target_state = "rest"
"""


def test_a_bonded_lift_planned_on_a_coarser_mesh_stays_exact_and_in_reach(tmp_path):
    """The trial's bonded case, small (about 4 s of CPU): the re-plans run on the planning mesh
    (3 x 2 x 2) while the first plan's expected pose came from the scenario's (4 x 2 x 2); the
    loop took their difference for the truth's and ended 0.239 um off (5.9 um on the trial's
    meshes) where the open loop is exact.  And after push 1 the remaining 1.38 mm counted from
    the loaded lower face (0.46 mm behind the gripper) was called beyond reach of 2 steps of
    0.6 mm: for a rest target the reach is counted from the rest the state springs back to."""
    (tmp_path / "truth.toml").write_text('name = "truth"' + COARSE_PLAN_BLOCK.format(
        elements=[4, 3, 2], young=2.6e6, mu_x=0.6, mu_y=0.33, angle=28.0))
    (tmp_path / "model.toml").write_text('name = "model"' + COARSE_PLAN_BLOCK.format(
        elements=[4, 2, 2], young=3.0e6, mu_x=0.5, mu_y=0.3, angle=35.0) + COARSE_REST_PLAN)
    assert main(["closed-loop", str(tmp_path / "model.toml"), "--truth", str(tmp_path / "truth.toml"), "--force",
                 "--out", str(tmp_path / "cl"), "--quiet", "--no-recording"]) == 0
    doc = json.loads((tmp_path / "cl" / "closed_loop.json").read_text())
    closed, opened = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    assert opened["position"] < 1e-9 and closed["position"] < 1e-9, (opened, closed)
    assert [it["plan_status"] for it in doc["iterations"]] == ["converged"] * 3, doc["iterations"]


def test_a_rest_targets_reach_is_counted_from_the_rest_its_state_springs_back_to():
    import dataclasses
    import tomllib

    from pushplan.config import parse_scenario
    from pushplan.config.plan import parse_plan
    from pushplan.planning.target import reach_message, reach_origin

    spec = parse_plan(parse_scenario(tomllib.loads('name = "m"' + COARSE_PLAN_BLOCK.format(
        elements=[3, 2, 2], young=3e6, mu_x=0.5, mu_y=0.3, angle=35.0) + COARSE_REST_PLAN)))
    # the trial's re-plan after push 1: 1.375 mm left from the lower face, 0.46 mm behind the gripper
    left = dataclasses.replace(spec, target=(1.375e-3 * 0.86, 1.375e-3 * 0.51, 0.0), steps=2)
    lag, fractions = np.array([0.46e-3 * 0.86, 0.46e-3 * 0.51, 0.0]), np.array([0.9, 0.9, 0.9])
    assert "beyond reach of 2 steps of 0.6 mm" in reach_message(left)
    assert np.allclose(reach_origin(left, lag, fractions), 0.9 * lag)
    assert reach_message(left, reach_origin(left, lag, fractions)) == ""
    # a loaded target carries its lag along: the reach is from the lower face
    loaded = dataclasses.replace(left, target_state="loaded")
    assert np.all(reach_origin(loaded, lag, fractions) == 0)
    assert "beyond reach" in reach_message(loaded, reach_origin(loaded, lag, fractions))
    # out of reach even from the spring-back: the message gives the distance from there
    far = dataclasses.replace(left, target=(2.0e-3, 0.0, 0.0))
    assert "target 1.657 mm" in reach_message(far, reach_origin(far, lag, fractions))
