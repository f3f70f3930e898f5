"""Robust plans in the loop and at rest (issue 42 item 4 and its hidden cases).

``closed-loop --identify`` with a ``[plan] robust`` table re-plans robustly over the
re-identified estimate and covariance after each push: it records the predicted probability
per re-plan, ends within the tolerance and no farther from the target than the nominal
closed loop on the same truth.  A robust plan to a rest target with a frictional pad (the
release by load control: no exact derivatives, Broyden-updated Jacobians): its Monte Carlo
fraction holds the predicted probability inside its 95 % binomial interval, and it does at
least as well as the nominal plan on the same truths."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pushplan.cli import main
from pushplan.identify.closed_loop import loop_distribution
from pushplan.planning.distribution import Distribution, pose_moments

from test_closed_loop import MODEL, PLAN, TOLERANCE

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
LOOP_ROBUST = "robust = {level = 0.9, max_iterations = 4, monte_carlo = 0}\n"


def _loop(tmp_path, name, plan_text):
    (tmp_path / f"{name}.toml").write_text(MODEL.format(mu_x=0.3, mu_y=0.15) + plan_text)
    out = tmp_path / name
    code = main(["closed-loop", str(tmp_path / f"{name}.toml"), "--truth", str(tmp_path / "truth.toml"), "--out",
                 str(out), "--quiet", "--no-recording", "--identify"])
    return code, json.loads((out / "closed_loop.json").read_text())


def test_the_factor_keeps_a_friction_variance_beside_a_modulus_in_pascal():
    """The sigma points of (mu_x, mu_y, angle, Young): eigh of C in SI units loses the friction
    variances in the modulus' rounding (it put a sigma point at mu_x = -21); the factor
    reproduces C to rounding relative to each pair's standard deviations, and the sigma
    points stay within sqrt(n + 1) standard deviations of the estimate."""
    sd = np.array([0.0013, 0.0033, 0.25, 8e8])
    corr = np.array([[1, 0.3, 0.2, 0.9], [0.3, 1, 0.1, 0.2], [0.2, 0.1, 1, 0.1], [0.9, 0.2, 0.1, 1]])
    d = Distribution(("mu_x", "mu_y", "angle_deg", "young"), np.array([0.39, 0.195, 25.0, 2.1e11]),
                     corr * np.outer(sd, sd))
    L = d.factor()
    assert np.all(np.abs(L @ L.T - d.covariance) <= 1e-12 * np.outer(sd, sd))
    points, weights = d.sigma_points()
    assert np.all(np.abs(points - d.mean) <= np.sqrt(5.0) * sd * (1 + 1e-9))
    mean, cov = pose_moments(points, weights)
    np.testing.assert_allclose(cov / np.outer(sd, sd), corr, atol=1e-9)


def test_the_loop_distribution_holds_undetermined_parameters_at_the_estimate():
    est = SimpleNamespace(names=("mu_x", "mu_y", "angle_deg", "young"), estimate=np.array([0.39, 0.15, 25.0, 2.1e11]),
                          sigma=np.array([0.0013, np.inf, 0.25, 8e8]), identifiable=(True, False, True, True),
                          correlation=np.array([[1.0, np.nan, 0.5, 0.1], [np.nan] * 4, [0.5, np.nan, 1.0, 0.0],
                                                [0.1, np.nan, 0.0, 1.0]]))
    d, held = loop_distribution(est)
    assert d.names == ("mu_x", "angle_deg", "young") and held == ("mu_y",)
    np.testing.assert_array_equal(d.mean, [0.39, 25.0, 2.1e11])
    assert d.covariance[0, 1] == 0.5 * 0.0013 * 0.25 and d.covariance[2, 2] == 8e8**2
    none = SimpleNamespace(**{**vars(est), "identifiable": (False,) * 4})
    assert loop_distribution(none) == (None, est.names)


def test_the_identified_loop_replans_robustly(tmp_path):
    (tmp_path / "truth.toml").write_text(MODEL.format(mu_x=0.39, mu_y=0.195))  # friction 30 % above the model's
    code_n, nominal = _loop(tmp_path, "nominal", PLAN)
    code_r, robust = _loop(tmp_path, "robust", PLAN + LOOP_ROBUST)
    print([it["robust"] for it in robust["iterations"]])
    print(nominal["closed_loop"]["final_error"], robust["closed_loop"]["final_error"])
    assert code_n == code_r == 0 and robust["robust"] and not nominal["robust"]
    its = robust["iterations"]
    assert its[0]["robust"] is None and its[0]["predicted_probability"] is None  # the first plan: no covariance yet
    for it in its[1:]:
        r = it["robust"]
        assert r is not None and 0.0 <= r["predicted_probability"] <= 1.0
        assert r["predicted_probability"] >= r["nominal_predicted_probability"]
        assert r["reached"] == (r["predicted_probability"] >= 0.9)
    closed = robust["closed_loop"]["final_error"]
    assert closed["within_tolerance"] and closed["position"] <= TOLERANCE
    assert closed["position"] <= nominal["closed_loop"]["final_error"]["position"]
    assert all(it["robust"] is None for it in nominal["iterations"])


REST_PAD = """
name = "rest_pad"
[block]
size = [0.04, 0.03, 0.02]
elements = [3, 2, 2]
quadrature = 2
[material]
young = 2e6
poisson = 0.45
density = 1000.0
[friction]
mu_x = 0.6
mu_y = 0.25
angle_deg = 20.0
[gripper]
friction = 0.9
[[load]]
dz = -4e-4
[release]
mode = "lift"
steps = 4
[plan]
x = 3e-3
y = 1e-3
steps = 4
max_step = 1.2e-3
tolerance = 2e-5
target_state = "rest"
planning_elements = [3, 2, 2]
planning_quadrature = 2
robust = {level = 0.85, max_iterations = 4, monte_carlo = 30, seed = 0}
"""
REST_IDENTIFIED = {"scenario": "rest_pad", "parameters": {
    "mu_x": {"estimate": 0.6, "sigma": 0.03}, "mu_y": {"estimate": 0.25, "sigma": 0.03},
    "angle_deg": {"estimate": 20.0, "sigma": 2.0}}, "correlation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}


@pytest.mark.slow
def test_a_robust_plan_to_a_rest_target_with_a_frictional_pad(tmp_path):
    """A pad of 0.9 lifted off a 0.6 / 0.25 floor by load control: the rest pose springs back by
    a part of the lag that depends on the friction, no exact derivatives (Broyden-updated
    Jacobians).  About 65 s of CPU: 30 truths, each rolling out both plans with the release."""
    (tmp_path / "case.toml").write_text(REST_PAD)
    (tmp_path / "identified.json").write_text(json.dumps(REST_IDENTIFIED))
    out = tmp_path / "out"
    code = main(["plan", str(tmp_path / "case.toml"), "--identified", str(tmp_path / "identified.json"), "--out",
                 str(out), "--quiet", "--no-recording"])
    doc = json.loads((out / "plan.json").read_text())
    r = doc["robust"]
    mc = r["monte_carlo"]
    print(r["predicted_probability"], r["nominal_predicted_probability"], mc["robust"], mc["nominal"])
    assert code == 0 and r["reached"] and not r["exact_jacobians"] and doc["plan"]["target_state"] == "rest"
    assert mc["robust"]["count"] == mc["nominal"]["count"] == 30
    for name, predicted in (("robust", r["predicted_probability"]), ("nominal", r["nominal_predicted_probability"])):
        lo, hi = mc[name]["interval_95"]
        assert lo <= predicted <= hi, (name, predicted, lo, hi)
    assert r["predicted_probability"] > r["nominal_predicted_probability"]
    assert mc["robust"]["within_tolerance"] >= mc["nominal"]["within_tolerance"]


ROTATED_IDENTIFIED = {"scenario": "plan_robust", "parameters": {
    "mu_x": {"estimate": 0.4, "sigma": 0.015}, "mu_y": {"estimate": 0.15, "sigma": 0.003},
    "angle_deg": {"estimate": 30.0, "sigma": 0.3}}, "correlation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}


@pytest.mark.slow
def test_a_robust_plan_on_rotated_axes_reaches_the_level_with_room_to_slide(tmp_path):
    """The friction axes at 30 degrees, the well-known one (mu_y) 75 degrees from the target's
    direction: the lag built along the badly known axis relaxes only over several steps of
    slide along the well-known one (benchmarks/robust_rotated.py), so with 5 steps the level
    is out of reach (0.47, exit 3) and with 10 the second start slides as long as the bounds
    allow and reaches 0.9.  About 80 s of CPU: 12 evaluations of 7 sigma points, 20 truths."""
    case = (SCENARIOS / "plan_robust.toml").read_text()
    case = (case.replace("mu_x = 0.3\n", "mu_x = 0.4\n").replace("angle_deg = 0.0\n", "angle_deg = 30.0\n")
            .replace("steps = 5\n", "steps = 10\n")
            .replace("monte_carlo = 50", "monte_carlo = 20"))
    assert "angle_deg = 30.0" in case and "steps = 10" in case and "monte_carlo = 20" in case
    (tmp_path / "case.toml").write_text(case)
    (tmp_path / "identified.json").write_text(json.dumps(ROTATED_IDENTIFIED))
    out = tmp_path / "out"
    code = main(["plan", str(tmp_path / "case.toml"), "--identified", str(tmp_path / "identified.json"), "--out",
                 str(out), "--quiet", "--no-recording"])
    r = json.loads((out / "plan.json").read_text())["robust"]
    mc = r["monte_carlo"]
    print(r["predicted_probability"], r["nominal_predicted_probability"], mc["robust"]["fraction"],
          mc["nominal"]["fraction"])
    assert code == 0 and r["reached"] and r["predicted_probability"] >= 0.9 > r["nominal_predicted_probability"]
    for name, predicted in (("robust", r["predicted_probability"]), ("nominal", r["nominal_predicted_probability"])):
        lo, hi = mc[name]["interval_95"]
        assert lo <= predicted <= hi, (name, predicted, lo, hi)
    assert mc["robust"]["within_tolerance"] > mc["nominal"]["within_tolerance"]


@pytest.mark.slow
def test_the_identified_loop_to_a_rest_target_replans_robustly(tmp_path):
    """The rest target of tests/test_episodes.py (a pad of 0.9 lifted off by load control; the
    truth's floor +25 %, Young +20 %, on a finer mesh) with --identify, nominal and robust
    re-plans: both within the tolerance, the robust loop no farther from the target, a
    probability recorded for each re-plan (about 100 s of CPU: identification and sigma points
    with the release at every push)."""
    from test_episodes import BLOCK, REST_PLAN

    (tmp_path / "t.toml").write_text('name = "t"' + BLOCK.format(elements=[4, 3, 2], young=2.4e6, mu_x=0.75,
                                                                  mu_y=0.3125, pad="0.9"))
    docs = {}
    for name, robust in (("nominal", ""), ("robust", "robust = {level = 0.9, max_iterations = 4}\n")):
        (tmp_path / f"{name}.toml").write_text('name = "m"' + BLOCK.format(elements=[3, 2, 2], young=2e6, mu_x=0.6,
                                                                             mu_y=0.25, pad="0.9") + REST_PLAN + robust)
        code = main(["closed-loop", str(tmp_path / f"{name}.toml"), "--truth", str(tmp_path / "t.toml"), "--out",
                     str(tmp_path / name), "--quiet", "--no-recording", "--identify", "--force"])
        assert code == 0
        docs[name] = json.loads((tmp_path / name / "closed_loop.json").read_text())
    nominal, robust = (docs[k]["closed_loop"]["final_error"] for k in ("nominal", "robust"))
    print(nominal, robust, [it["predicted_probability"] for it in docs["robust"]["iterations"]])
    assert robust["within_tolerance"] and robust["position"] <= nominal["position"]
    assert all(it["robust"] is not None for it in docs["robust"]["iterations"][1:])
    assert docs["robust"]["scored_on"] == "rest pose after the truth's release"
