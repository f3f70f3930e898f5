"""Issue 43/45 hardening: one convention for every stated cap (a cap of
:mod:`pushplan.limits` admits its own value, the next float is refused with "<="), the
co-simulation's step budget refused for its own reason, and the messages that must name
their file or object."""

import argparse
import math

import pytest

from pushplan import limits
from pushplan.cli.args import real
from pushplan.config.mujoco import bridge_settings
from pushplan.config.scenario import _stiffness
from pushplan.config.validate import Table
from pushplan.errors import InputError
from pushplan.identify.noise import NoiseModel
from pushplan.mujoco.mjmodel import check_mujoco_work

CAPPED = {  # every file key and library argument capped by pushplan.limits: (build with value, cap)
    "force_noise": (lambda v: NoiseModel(force_noise=v), limits.MAX_FORCE_NOISE),
    "force_noise_rel": (lambda v: NoiseModel(force_noise_rel=v), limits.MAX_FORCE_NOISE_REL),
    "mujoco.control_period": (lambda v: bridge_settings({"control_period": v}), limits.MAX_CONTROL_PERIOD),
    "mujoco.settle_time": (lambda v: bridge_settings({"settle_time": v}), limits.MAX_CONTROL_PERIOD),
    "gripper.stiffness_xy": (lambda v: _stiffness(Table({"stiffness_xy": v}, "gripper", {"stiffness_xy"}),
                                                  "stiffness_xy"), limits.MAX_GRIPPER_STIFFNESS),
}


@pytest.mark.parametrize("key", sorted(CAPPED))
def test_a_file_cap_admits_its_value_and_refuses_the_next_float(key):
    build, cap = CAPPED[key]
    build(cap)  # "at most": the cap itself is allowed
    with pytest.raises(InputError, match=rf"must be <= {cap:g}|must be <= {cap}"):
        build(math.nextafter(cap, math.inf))


@pytest.mark.parametrize("cap", [limits.MAX_FORCE_NOISE, limits.MAX_FORCE_NOISE_REL, limits.MAX_CONTROL_PERIOD,
                                 limits.MAX_RATIO, limits.MAX_POSE_NOISE])
def test_an_option_cap_admits_its_value_and_refuses_the_next_float(cap):
    parse = real(0.0, cap)
    assert parse(repr(cap)) == cap
    with pytest.raises(argparse.ArgumentTypeError, match="<="):
        parse(repr(math.nextafter(cap, math.inf)))


def test_the_step_budget_is_refused_for_the_steps_not_the_period():
    check_mujoco_work(1000, limits.MAX_CONTROL_PERIOD, 1e-3)  # 1e7 steps: exactly the budget
    with pytest.raises(InputError, match=r"1\.00?1e\+07 steps, more than 10000000"):
        check_mujoco_work(1001, limits.MAX_CONTROL_PERIOD, 1e-3)


# ---- MuJoCo objects by index ------------------------------------------------------------

def test_an_object_index_past_the_last_is_bad_input_naming_the_count():
    mujoco = pytest.importorskip("mujoco", reason="the MuJoCo extra is not installed")
    from pushplan.mujoco.mjmodel import find_object

    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom type='plane' size='1 1 .1'/>"
                                       "<geom type='box' size='.1 .1 .1' pos='0 0 1'/></worldbody></mujoco>")
    assert find_object(m, mujoco.mjtObj.mjOBJ_GEOM, "#1", "floor") == 1
    for name in ("#2", "#999", "#" + "9" * 400):
        with pytest.raises(InputError, match=r"floor '#9*.*2 geom\(s\), numbered #0 to #1"):
            find_object(m, mujoco.mjtObj.mjOBJ_GEOM, name, "floor")


# ---- a full disk while rerun writes a recording -----------------------------------------

SMALL = """
name = "disk"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
[material]
young = 210e9
poisson = 0.3
[friction]
mu_x = 0.3
mu_y = 0.1
[[load]]
dz = -1e-4
[[load]]
dx = 2e-5
[solver]
local_method = "newton"
"""

FULL_DISK = """
import sys
import rerun
from pushplan.cli import main

def save(self, *args, **kwargs):  # what rerun 0.41 raises when its file sink meets ENOSPC
    raise RuntimeError("Failed to encode LogMsg: failed to write: No space left on device (os error 28)")

rerun.RecordingStream.{method} = save
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("method", ["save", "disconnect"])
def test_a_full_disk_under_a_recording_is_one_line_naming_the_file(tmp_path, method):
    pytest.importorskip("rerun", reason="the rerun extra is not installed")
    import os
    import subprocess
    import sys

    (tmp_path / "s.toml").write_text(SMALL)
    out = tmp_path / "out"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1"}
    first = subprocess.run([sys.executable, "-m", "pushplan.cli", "simulate", "s.toml", "--out", "out", "--quiet"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = subprocess.run([sys.executable, "-c", FULL_DISK.format(method=method), "simulate", "s.toml", "--out",
                           "out", "--quiet"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert "recording.rrd" in lines[0] and "no space left" in lines[0].lower(), lines
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the old output whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "s.toml"]  # nothing half-written
