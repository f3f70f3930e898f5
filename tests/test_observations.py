"""Observation files (issue 20): the CSV and JSON forms read into the same
observations, ``pushplan simulate --observations`` writes what the run's summary
holds (force on the gripper = minus the drive force on the block), and bad files are
refused with a one-line message naming the row / column, exit 2, nothing written."""

import json
import math

import numpy as np
import pytest

from pushplan.cli import EXIT_BAD_INPUT, main
from pushplan.config.observations import (
    OBSERVED_COLUMNS, Observations, observations_to_csv, observations_to_json, parse_csv, parse_json,
    read_observations,
)
from pushplan.errors import InputError

SCENARIO = """
name = "obs"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
quadrature = 2
[material]
young = 210e9
poisson = 0.3
[friction]
mu_x = 0.3
mu_y = 0.15
angle_deg = 20.0
[[load]]
dz = -1e-4
[[load]]
distance = 0.1e-3
direction_deg = 60.0
repeat = 2
[solver]
local_method = "newton"
"""

GOOD = """# a comment line
dx,dy,dz,dtheta_deg,lower_x,force_y
0,0,-1e-4,0,0,0.5
1e-4,0,0,0.5,2e-5,-3.25
"""


def test_csv_and_json_read_the_same_and_round_trip():
    obs = parse_csv(GOOD)
    assert obs.columns == ("lower_x", "force_y")
    assert obs.commands[1].dx == 1e-4 and obs.commands[1].dtheta == math.radians(0.5)
    assert obs.values["force_y"].tolist() == [0.5, -3.25]
    again = parse_json(json.loads(json.dumps(observations_to_json(obs))))
    assert again.commands == obs.commands
    assert {k: v.tolist() for k, v in again.values.items()} == {k: v.tolist() for k, v in obs.values.items()}
    text = parse_csv(observations_to_csv(obs))
    assert text.commands == obs.commands and text.values["lower_x"].tolist() == [0.0, 2e-5]


@pytest.mark.parametrize("text, fragments", [
    ("dx,dy,dz,lower_x\n0,0,0,1\n", ["missing column dtheta_deg"]),
    ("dx,dy,dz,dtheta_deg,lower_x\n0,0,0,0,nan\n", ["row 1 column lower_x", "finite"]),
    ("dx,dy,dz,dtheta_deg,lower_x\n0,0,0,0,1\n0,0,0,0\n", ["row 2 has 4 values"]),
    ("dx,dy,dz,dtheta_deg,lower_z\n0,0,0,0,1\n", ["unknown column 'lower_z'"]),
    ("", ["empty"]),
    ("dx,dy,dz,dtheta_deg\n", ["no rows"]),
    ("dx,dy,dz,dtheta_deg,force_x\n0,0,0,0,abc\n", ["row 1 column force_x", "'abc'"]),
])
def test_bad_csv_is_named(text, fragments):
    with pytest.raises(InputError) as exc:
        parse_csv(text, "f.csv")
    for f in fragments:
        assert f in str(exc.value)


def test_bad_json_rows():
    with pytest.raises(InputError, match="row 2 has columns"):
        parse_json({"observations": [{"dx": 0, "dy": 0, "dz": 0, "dtheta_deg": 0},
                                     {"dx": 0, "dy": 0, "dz": 0, "dtheta_deg": 0, "force_x": 1}]})
    with pytest.raises(InputError, match="no rows"):
        parse_json({"observations": []})
    with pytest.raises(InputError, match="must be finite"):
        Observations(parse_csv(GOOD).commands, {"force_x": np.array([1.0, np.inf])})


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_simulate_writes_observations_of_the_run(tmp_path, suffix):
    (tmp_path / "s.toml").write_text(SCENARIO)
    path = tmp_path / f"obs{suffix}"
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet",
                 "--no-recording", "--observations", str(path)]) == 0
    obs = read_observations(path)
    steps = json.loads((tmp_path / "o" / "summary.json").read_text())["steps"]
    assert obs.columns == OBSERVED_COLUMNS and len(obs) == len(steps) == 3
    for i, s in enumerate(steps):
        assert obs.values["lower_x"][i] == s["lower_centroid"][0]
        assert obs.values["lower_y"][i] == s["lower_centroid"][1]
        assert obs.values["lower_yaw_deg"][i] == s["lower_yaw_deg"]
        # the force on the block (docs/conventions.md): upper_force
        assert [obs.values[k][i] for k in ("force_x", "force_y", "force_z")] == list(s["upper_force"])
        assert obs.commands[i].dx == s["command"]["dx"] and obs.commands[i].dz == s["command"]["dz"]
    # physics (forces on the block): the gripper presses it down and drags it along the 60 deg push
    assert obs.values["force_z"][0] < 0
    assert obs.values["force_x"][-1] > 0 and obs.values["force_y"][-1] > 0


def test_simulate_refuses_an_unknown_observation_format(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(SCENARIO)
    code = main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet",
                 "--observations", str(tmp_path / "obs.txt")])
    assert code == EXIT_BAD_INPUT
    assert "must end in .csv or .json" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [tmp_path / "s.toml"]
