"""A bug is not bad input (issue 27): bad input is recognised where it is parsed and
exits 2 with one line naming the key and value; a ``ValueError`` raised deeper (in
``fe_contact`` while building the model, in the driver, in the recording reader) is
a bug and keeps its traceback (exit 1)."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from pushplan.cli import EXIT_BAD_INPUT, main
from pushplan.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
BUG = "operands could not be broadcast together with shapes (3,) (2,)"  # the injected bug

# a broadcasting bug injected inside fe_contact/fem/mesh.py (block_mesh calls _check_size)
INJECT_MESH_BUG = (
    "import sys\n"
    "import fe_contact.fem.mesh as mesh\n"
    "def broken(size):\n"
    f"    raise ValueError({BUG!r})\n"
    "mesh._check_size = broken\n"
    "from pushplan.cli import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


def test_a_value_error_inside_fe_contact_exits_1_with_its_traceback(tmp_path):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", INJECT_MESH_BUG, "simulate", str(ROOT / "scenarios/paper_case1.toml"),
                           "--out", str(tmp_path / "out"), "--quiet", "--no-recording"],
                          capture_output=True, text=True, env=env, timeout=300, cwd=ROOT)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" in proc.stderr and f"ValueError: {BUG}" in proc.stderr
    assert 'fe_contact/fem/mesh.py", line' in proc.stderr  # the traceback reaches the bug
    assert "pushplan: error" not in proc.stderr
    assert not (tmp_path / "out").exists()


def test_scenario_model_lets_a_value_error_through(monkeypatch):
    from pushplan.config import scenario as scenario_module
    from pushplan.config import load_scenario

    sc = load_scenario(ROOT / "scenarios/paper_case1.toml")

    def broken(size, divisions):
        raise ValueError(BUG)

    monkeypatch.setattr(scenario_module, "block_mesh", broken)
    with pytest.raises(ValueError, match="operands could not be broadcast") as info:
        sc.model()
    assert not isinstance(info.value, InputError)  # InputError is a ValueError: exit 2, no traceback


def test_driver_rejects_a_non_command_as_a_bug():
    from fe_contact import build_model
    from pushplan.run.driver import drive

    model = build_model((0.02, 0.02, 0.01), (1, 1, 1), 2.1e11, 0.3, 0.3, 0.1, quadrature=2)
    with pytest.raises(TypeError, match=r"commands\[0\] must be a fe_contact.Command, got dict"):
        drive(model, [{"dz": -1e-4}])


def test_a_corrupt_recording_is_bad_input_and_a_reader_bug_is_not(tmp_path, monkeypatch, capsys):
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not an rrd file")
    assert main(["replay", str(bad), "--out", str(tmp_path / "out")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("pushplan: error: cannot read recording") and str(bad) in err
    assert len(err.strip().splitlines()) == 1

    import rerun.chunk

    from pushplan.outputs.recording_read import read_recording

    class Broken:
        def __init__(self, path):
            raise ValueError(BUG)

    monkeypatch.setattr(rerun.chunk, "RrdReader", Broken)
    with pytest.raises(ValueError, match="operands could not be broadcast") as info:
        read_recording(bad)
    assert not isinstance(info.value, InputError)


def test_mujoco_elements_override_is_checked_where_parsed(capsys):
    assert main(["mujoco", "compare", "scene.toml", "--elements", "2", "0", "1"]) == EXIT_BAD_INPUT
    assert "argument --elements: must be an integer from 1" in capsys.readouterr().err


@pytest.mark.parametrize("key", ["pad_regularisation"])
def test_solver_stiffnesses_are_checked_where_parsed(key):
    from pushplan.config import parse_scenario
    from tiny_inputs import BASE

    data = tomllib.loads(BASE)
    data["solver"] = {key: -0.1}
    with pytest.raises(InputError, match=rf"solver.{key} must be > 0, got -0.1"):
        parse_scenario(data)
