"""The input schema (issue 18): scenario files survive a round trip through
``to_dict``; the command codec is exact; the one validation style names the key."""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fe_contact import Command
from pushplan.config import load_scenario, parse_scenario
from pushplan.config.commands import command_from_dict, command_to_dict, degrees_exact, load_commands
from pushplan.config.validate import Table
from pushplan.errors import InputError

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
SCENARIO_FILES = sorted(p for p in SCENARIOS.glob("*.toml") if "base" not in tomllib.loads(p.read_text()))


def test_every_shipped_scenario_is_checked():
    assert len(SCENARIO_FILES) >= 8


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: p.name)
def test_scenario_round_trip(path):
    scenario = load_scenario(path)
    again = parse_scenario(scenario.to_dict())
    assert again == scenario
    assert again.to_dict() == scenario.to_dict()


def test_round_trip_keeps_solver_defaults_and_extra_tables():
    text = (SCENARIOS / "plan_steel_case3.toml").read_text()
    scenario = load_scenario(SCENARIOS / "plan_steel_case3.toml")
    data = scenario.to_dict()
    assert "local_max_iter" not in data["solver"]  # None is not a value a file can hold
    assert data["plan"] == tomllib.loads(text)["plan"]


def test_degrees_exact_gives_the_radians_back():
    rng = np.random.default_rng(3)
    degrees = np.concatenate([rng.uniform(-360, 360, 2000), np.arange(-180, 181, 0.1)])
    missed = 0
    for d in degrees:
        angle = math.radians(float(d))
        assert math.radians(degrees_exact(angle)) == angle
        missed += math.radians(math.degrees(angle)) != angle
    assert missed > 0  # the naive conversion is not exact: the test could fail


def test_command_codec_round_trip_and_errors():
    c = Command(1e-4, -2e-4, -1e-5, math.radians(0.3))
    assert command_from_dict(command_to_dict(c), "c") == c
    with pytest.raises(InputError, match=r"commands\[2\]\.dx must be a number, got 'far'"):
        command_from_dict({"dx": "far"}, "commands[2]")
    with pytest.raises(InputError, match=r"unknown key c\.speed"):
        command_from_dict({"speed": 1.0}, "c")


def test_load_commands_names_the_file(tmp_path):
    f = tmp_path / "plan.json"
    f.write_text('{"commands": [{"dx": 1e-4}, {"dtheta_deg": "x"}]}')
    with pytest.raises(InputError, match=r"plan.json: commands\[1\]\.dtheta_deg"):
        load_commands(f)
    f.write_text("[" * 100_000)
    with pytest.raises(InputError, match="cannot read commands file"):
        load_commands(f)


def test_table_names_the_full_key():
    t = Table({"x": 1.0, "n": 2.5}, "plan", {"x", "n", "y"}, required={"x"})
    assert t.number("x", positive=True) == 1.0
    assert t.number("y", 3.0) == 3.0
    with pytest.raises(InputError, match=r"plan\.n must be an integer, got 2\.5"):
        t.integer("n")
    with pytest.raises(InputError, match=r"missing key plan\.y"):
        Table({}, "plan", {"y"}, required={"y"})
    with pytest.raises(InputError, match=r"unknown key plan\.z"):
        Table({"z": 1}, "plan", {"y"})
