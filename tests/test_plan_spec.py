"""The ``[plan]`` table (pushplan.config.plan): its round trip, the names in its
messages, and a failed FE rollout as a solver failure (exit 3, no plan.json)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from pushplan.cli import main
from pushplan.config import parse_scenario
from pushplan.config.plan import PLAN_KEYS, PlanSpec, parse_plan
from pushplan.errors import EXIT_SOLVER_FAILURE, InputError, SolverFailure
from pushplan.planning import PlanningError

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
PLANNING_SCENARIOS = ("plan_steel_case3", "plan_rubber", "plan_rotated_axes", "plan_yaw")


def scenario_data(name: str) -> dict:
    return tomllib.loads((SCENARIOS / f"{name}.toml").read_text())


@pytest.mark.parametrize("name", PLANNING_SCENARIOS)
def test_plan_table_round_trip(name):
    """``parse_plan`` reads ``spec.to_table()`` back as the same spec, bit for bit."""
    scenario = parse_scenario(scenario_data(name))
    spec = parse_plan(scenario)
    again = parse_plan(parse_scenario({**scenario.to_dict(), "plan": spec.to_table()}))
    assert again == spec
    assert isinstance(spec, PlanSpec)
    assert set(spec.to_table()) <= PLAN_KEYS and set(spec.to_dict()) == PLAN_KEYS | {"travel"}


def test_plan_defaults():
    data = scenario_data("plan_steel_case3")
    data["plan"] = {"x": 3e-4, "y": 4e-4, "steps": 2, "max_step": 3e-4}
    spec = parse_plan(parse_scenario(data))
    assert spec.tolerance == pytest.approx(0.0025 * 5e-4)
    assert (spec.planning_elements, spec.planning_quadrature, spec.max_rollouts) == ((6, 6, 2), 2, 6)
    assert not spec.yaw_targeted and spec.target[2] == 0.0 and spec.max_dtheta == 0.0


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["plan"].update(planning_quadrature=4), "plan.planning_quadrature must be <= 3, got 4"),
    (lambda d: d["plan"].update(planning_elements=[4, 0, 2]), "plan.planning_elements[1] must be >= 1, got 0"),
    (lambda d: d["plan"].update(effort_weight=-1.0), "plan.effort_weight must be >= 0, got -1.0"),
    (lambda d: d["plan"].update(yaw_deg=180.0, max_dtheta_deg=1.0), "plan.yaw_deg must be < 180.0, got 180.0"),
    (lambda d: d["plan"].update(x=0.0, y=0.0, tolerance=None) or d["plan"].pop("tolerance"),
     "plan.tolerance is required"),
    (lambda d: d.pop("plan"), "has no [plan] table"),
    (lambda d: d["friction"].update(mu_y=0.0), "friction in both directions"),
])
def test_bad_plan_value_names_key_and_value(edit, message):
    data = scenario_data("plan_steel_case3")
    edit(data)
    with pytest.raises(InputError, match=re.escape(message)):
        parse_plan(parse_scenario(data))


def test_failed_rollout_is_a_solver_failure(tmp_path, capsys):
    """An FE step that does not converge raises PlanningError (a SolverFailure): exit 3,
    the failed step named on stderr, no plan.json."""
    assert issubclass(PlanningError, SolverFailure)
    text = (SCENARIOS / "plan_steel_case3.toml").read_text()
    text = text.replace('local_method = "newton"', 'local_method = "newton"\nnewton_max_iter = 1')
    text = text.replace("elements = [12, 12, 4]", "elements = [4, 4, 2]").replace("quadrature = 3", "quadrature = 2")
    scenario_file = tmp_path / "stiff.toml"
    scenario_file.write_text(text)
    out = tmp_path / "plan"
    assert main(["plan", str(scenario_file), "--out", str(out), "--quiet", "--no-recording"]) == EXIT_SOLVER_FAILURE
    err = capsys.readouterr().err
    assert re.search(r"pushplan: solver failure: FE step \d+ on the planning mesh failed", err), err
    assert not (out / "plan.json").exists()
