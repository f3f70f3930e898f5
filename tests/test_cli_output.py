"""What the terminal shows (issue 22): --version, --quiet that is quiet, no carriage
returns in logs, forces in N with engineering prefixes, no twist while the block sticks,
a warning for values in the wrong unit."""

import subprocess
import sys

import pytest

from pushplan.cli import main
from pushplan.cli.units import engineering

SCENARIO = """
name = "output"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
quadrature = 2
[material]
young = {young}
poisson = 0.3
[friction]
mu_x = 0.3
mu_y = 0.1
[[load]]
dz = -1e-4
[[load]]
distance = 0.32e-3
direction_deg = 45.0
"""


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(young="210e9"))
    return path


def test_version():
    out = subprocess.run([sys.executable, "-m", "pushplan.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("pushplan ")


def test_quiet_prints_nothing(scenario, tmp_path, capsys):
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "o"), "--quiet", "--no-recording"]) == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


def test_table_and_progress_read_as_a_log(scenario, tmp_path, capsys):
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "o"), "--no-recording"]) == 0
    captured = capsys.readouterr()
    assert "\r" not in captured.out + captured.err  # not a terminal: one line per step
    assert captured.err.count("step ") == 2
    rows = [line.split() for line in captured.out.splitlines() if line.strip()[:1].isdigit()]
    press, push = rows
    assert "-" in press  # the press moves nothing in the plane: no twist
    assert any(cell.endswith("°") for cell in push[5:7])
    assert "MN" in press or "kN" in press  # ~1e5-1e6 N for a steel block pressed 0.1 mm


@pytest.mark.parametrize("recording", [True, False])
def test_the_last_line_names_every_file_written(scenario, tmp_path, capsys, recording):
    out = tmp_path / "o"
    assert main(["simulate", str(scenario), "--out", str(out)] + ([] if recording else ["--no-recording"])) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    files = sorted(p.name for p in out.iterdir())
    assert files == sorted(["summary.json", "fields.npz"] + (["recording.rrd"] if recording else []))
    assert last.startswith("wrote ") and all(str(out / name) in last for name in files)


@pytest.mark.parametrize("value, text", [(60.2, "60.2 N"), (9.0898e5, "909 kN"), (2.5e-3, "2.5 mN"),
                                         (0.0, "0 N"), (-1.5e7, "-15 MN")])
def test_engineering_prefixes(value, text):
    assert engineering(value, "N", digits=3) == text


def test_modulus_in_the_wrong_unit_is_warned_about(tmp_path, capsys):
    path = tmp_path / "soft.toml"
    path.write_text(SCENARIO.format(young="2.0"))  # MPa meant, Pa given
    main(["simulate", str(path), "--out", str(tmp_path / "o"), "--quiet", "--no-recording"])
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("pushplan: warning: material.young = 2 Pa")
