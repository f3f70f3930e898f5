"""Robust plans (issue 42): the sigma points and the Gaussian success probability against
closed forms, the ``[plan] robust`` table and ``--identified`` refused with one line,
a zero covariance giving the nominal plan back, a level no commands reach said so (exit 3),
and (slow) the acceptance case: a nominal plan whose Monte Carlo success over 50 truths
from the identified distribution is below 60 % against a robust one at or above 90 %, each
prediction inside its Monte Carlo's 95 % binomial interval."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import beta

from pushplan.cli import EXIT_BAD_INPUT, EXIT_SOLVER_FAILURE, main
from pushplan.config import parse_scenario
from pushplan.config.plan import parse_plan
from pushplan.errors import InputError
from pushplan.identify.document import read_identified
from pushplan.planning import plan
from pushplan.planning.distribution import Distribution, binomial_interval, pose_moments, success_probability
from pushplan.planning.robust import plan_robust

QMC_ATOL = 3e-3  # success_probability's quasi-Monte Carlo against the closed form
ACCEPT_NOMINAL = 0.60  # issue 42: nominal Monte Carlo success below this ...
ACCEPT_ROBUST = 0.90  # ... robust at or above this, at the same tolerance

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
CASE = (SCENARIOS / "plan_robust.toml").read_text()
ROBUST = "robust = {level = 0.9, max_iterations = 12, monte_carlo = 50, seed = 0}\n"
assert ROBUST in CASE
CASE = CASE.replace(ROBUST, "")
# the kind of distribution identification reports (issue 42: mu_x +- 0.003, mu_y +- 0.014, angle +- 0.6 deg):
# mu_y, across the push, much less certain than mu_x
IDENTIFIED = json.loads((SCENARIOS / "plan_robust_identified.json").read_text())


def write(tmp_path, robust=ROBUST, identified=IDENTIFIED, case=CASE):
    (tmp_path / "case.toml").write_text(case + robust)
    (tmp_path / "identified.json").write_text(json.dumps(identified))
    return str(tmp_path / "case.toml"), str(tmp_path / "identified.json")


def run_plan(tmp_path, robust=ROBUST, identified=IDENTIFIED, case=CASE):
    case, ident = write(tmp_path, robust, identified, case)
    out = tmp_path / "out"
    rc = main(["plan", case, "--identified", ident, "--out", str(out), "--quiet", "--no-recording"])
    return rc, json.loads((out / "plan.json").read_text())


def test_sigma_points_reproduce_the_moments_and_a_linear_map():
    C = np.array([[4e-6, 1e-6, 0.0], [1e-6, 4e-4, 0.0], [0.0, 0.0, 1.0]])
    d = Distribution(("mu_x", "mu_y", "angle_deg"), np.array([0.3, 0.15, 5.0]), C)
    pts, w = d.sigma_points()
    assert len(pts) == 7 and np.all(w > 0) and math.isclose(w.sum(), 1.0)
    mean, cov = pose_moments(pts, w)
    np.testing.assert_allclose(mean, d.mean, rtol=1e-12)
    np.testing.assert_allclose(cov, C, atol=1e-15)
    A = np.array([[1.0, -2.0, 0.1], [0.5, 3.0, 0.0], [0.0, 0.0, 2.0]])  # p = A theta: mean A m, covariance A C A^T
    mean, cov = pose_moments(pts @ A.T, w)
    np.testing.assert_allclose(cov, A @ C @ A.T, atol=1e-14)
    zero = Distribution(d.names, d.mean, np.zeros((3, 3)))
    assert zero.zero and len(zero.sigma_points()[0]) == 1


def test_success_probability_against_the_rayleigh_closed_form():
    spec = parse_plan(parse_scenario(tomlish(CASE)))
    tol = spec.tolerance
    target = np.array([*spec.target[:2], 0.0])
    for s in (0.3 * tol, tol, 2.0 * tol):  # isotropic, centred: P(|e| <= tol) = 1 - exp(-tol^2 / (2 s^2))
        p = success_probability(target, np.diag([s * s, s * s, 0.0]), spec)
        assert abs(p - (1 - math.exp(-tol**2 / (2 * s * s)))) < QMC_ATOL
    assert success_probability(target + [0.99 * tol, 0, 0], np.zeros((3, 3)), spec) == 1.0
    assert success_probability(target + [1.01 * tol, 0, 0], np.zeros((3, 3)), spec) == 0.0


def test_binomial_interval_is_clopper_pearson():
    lo, hi = binomial_interval(47, 50)
    assert math.isclose(lo, beta.ppf(0.025, 47, 4), rel_tol=1e-6)
    assert math.isclose(hi, beta.ppf(0.975, 48, 3), rel_tol=1e-6)
    assert binomial_interval(50, 50)[1] == 1.0 and binomial_interval(0, 50)[0] == 0.0


def tomlish(text):
    import tomllib

    return tomllib.loads(text)


@pytest.mark.parametrize("robust, message", [
    ("robust = {level = 1.0}\n", "plan.robust.level must be a probability in (0, 1), got 1.0"),
    ("robust = {level = 0.9, samples = 3}\n", "samples"),
    ("robust = {monte_carlo = -1}\n", "plan.robust.monte_carlo"),
    ("robust = {max_iterations = 0}\n", "plan.robust.max_iterations"),
    ("robust = 0.95\n", "plan.robust"),
])
def test_robust_table_is_validated(tmp_path, capsys, robust, message):
    case, ident = write(tmp_path, robust)
    assert main(["plan", case, "--identified", ident, "--out", str(tmp_path / "o"), "--quiet"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["parameters"]["mu_y"].update(sigma=None), "parameters.mu_y.sigma is null"),
    (lambda d: d["parameters"].update(poisson={"estimate": 0.3, "sigma": 0.01}), "parameters.poisson"),
    (lambda d: d.update(correlation=[[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "positive semi-definite"),
    (lambda d: d.update(correlation=[[1.0]]), "correlation must be 3 x 3"),
    (lambda d: d.pop("parameters"), "is not an identified.json"),
])
def test_identified_file_is_validated(tmp_path, capsys, edit, message):
    doc = json.loads(json.dumps(IDENTIFIED))
    edit(doc)
    case, ident = write(tmp_path, identified=doc)
    with pytest.raises(InputError, match="--identified"):
        read_identified(ident)
    assert main(["plan", case, "--identified", ident, "--out", str(tmp_path / "o"), "--quiet"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_zero_covariance_gives_the_nominal_plan():
    scenario = parse_scenario(tomlish(CASE + "robust = {monte_carlo = 2}\n"))
    d = Distribution(("mu_x", "mu_y", "angle_deg"), np.array([0.3, 0.15, 0.0]), np.zeros((3, 3)))
    scenario = d.scenario(scenario, d.mean)
    spec = parse_plan(scenario)
    nominal = plan(scenario, spec, baseline=False)
    assert nominal.status == "converged"
    robust = plan_robust(scenario, d, spec, nominal)
    assert robust.reached and robust.evaluations[robust.best].probability == 1.0
    np.testing.assert_array_equal(robust.result.commands, nominal.commands)
    np.testing.assert_allclose(robust.result.verified.final(), nominal.verified.final(), atol=1e-12)
    # every truth is the estimate: both plans within tolerance in each
    assert robust.monte_carlo["robust"].within == robust.monte_carlo["nominal"].within == 2


def test_a_level_not_reached_exits_3_with_the_best_probability(tmp_path):
    rc, doc = run_plan(tmp_path, "robust = {level = 0.999, max_iterations = 2, monte_carlo = 0}\n")
    r = doc["robust"]
    assert rc == EXIT_SOLVER_FAILURE and doc["status"] == "not_converged" and not r["reached"]
    probs = [e["predicted_probability"] for e in r["evaluations"]]
    assert len(probs) == 2 and r["predicted_probability"] == max(probs) < 0.999
    assert "highest probability found" in doc["message"]
    assert r["fe_rollouts"]["sigma_point_rollouts"] == 2 * 7 and r["monte_carlo"]["truths"] == 0


@pytest.mark.slow
def test_robust_plan_holds_where_the_nominal_does_not(tmp_path):
    """Issue 42's acceptance (about 30 s): 50 truths, the same tolerance for both plans."""
    rc, doc = run_plan(tmp_path)
    r = doc["robust"]
    assert rc == 0 and r["reached"] and doc["status"] == "converged"
    mc = r["monte_carlo"]
    assert mc["truths"] >= 50 and mc["robust"]["count"] == mc["nominal"]["count"] == mc["truths"]
    assert mc["nominal"]["fraction"] < ACCEPT_NOMINAL <= ACCEPT_ROBUST <= mc["robust"]["fraction"]
    for name, predicted in (("robust", r["predicted_probability"]), ("nominal", r["nominal_predicted_probability"])):
        lo, hi = mc[name]["interval_95"]
        assert lo <= predicted <= hi, (name, predicted, lo, hi)
    # the plan.json commands are the robust ones, the nominal ones beside them
    assert doc["planned_commands"] != r["nominal"]["commands"]


def test_rest_target_with_a_bonded_lift_holds_for_every_friction(tmp_path):
    """A bonded pad lifted off leaves the lower face under the upper face whatever the friction:
    the rest target's spread is nil, the nominal plan already holds, and the robust plan (sigma-point
    rollouts with the release, no exact Jacobian) says so after one evaluation and keeps it."""
    rest = CASE.replace("[plan]\n", '[release]\nmode = "lift"\nsteps = 4\n\n[plan]\ntarget_state = "rest"\n')
    rc, doc = run_plan(tmp_path, "robust = {monte_carlo = 2}\n", case=rest)
    r = doc["robust"]
    assert rc == 0 and r["reached"] and not r["exact_jacobians"] and doc["plan"]["target_state"] == "rest"
    assert r["predicted_probability"] == r["nominal_predicted_probability"] == 1.0 and len(r["evaluations"]) == 1
    assert doc["planned_commands"] == r["nominal"]["commands"]
    assert r["monte_carlo"]["robust"]["within_tolerance"] == r["monte_carlo"]["nominal"]["within_tolerance"] == 2
    assert r["evaluations"][0]["sd_final"][0] < 0.01 * doc["plan"]["tolerance"]
