"""``kill -9`` of the commands that write ``--out`` beyond simulate and sweep (issue 34):
at the stages of the transaction (its folder created, its first file written, its
last file written: the swap follows) the folder holds the previous complete output or
the new complete one, never a mix; the next run removes what the killed one left.
A closed loop without a recording keeps no recording of the run before it."""

import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pushplan.cli import main
from tiny_inputs import BASE, OBSERVATIONS, PLAN

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1",
       "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
XML = ROOT / "scenarios" / "mujoco_push.xml"

# command: (argv after the command name, with {tmp} and {out}; the files it owns, in writing order)
COMMANDS = {
    "identify": (["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}", "--quiet"],
                 ("identified.json", "identified.toml")),
    "closed-loop": (["closed-loop", "{tmp}/p.toml", "--truth", "{tmp}/t.toml", "--out", "{out}", "--quiet"],
                    ("closed_loop.json", "recording.rrd")),
    "plan": (["plan", "{tmp}/p.toml", "--out", "{out}", "--quiet"], ("plan.json", "recording.rrd")),
    "mujoco cosim": (["mujoco", "cosim", str(XML), "--commands", "{tmp}/c.json", "--out", "{out}", "--quiet"],
                     ("cosim.json", "cosim.rrd")),
}


def snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def setup(tmp: Path, owned) -> Path:
    for name, text in (("s.toml", BASE), ("p.toml", PLAN), ("t.toml", PLAN.replace("mu_y = 0.1", "mu_y = 0.12")),
                       ("o.csv", OBSERVATIONS), ("c.json", '{"commands": [{"dz": -1e-4}, {"dx": 1e-5}]}')):
        (tmp / name).write_text(text)
    out = tmp / "out"
    out.mkdir()
    for name in owned:  # a previous output of the same files, and one file of the user's
        (out / name).write_text("previous")
    (out / "notes.txt").write_text("kept across runs")
    return out


def staged(parent: Path, name: str | None):
    def ready() -> bool:
        found = [*parent.glob(".out.*.partial"), *parent.glob(".out.*.ready")]
        return bool(found) and (name is None or any((f / name).exists() for f in found))
    return ready


def kill_at(proc, condition, timeout=120.0) -> None:
    t0 = time.monotonic()
    while not condition() and proc.poll() is None and time.monotonic() - t0 < timeout:
        time.sleep(0.002)
    if proc.poll() is None:
        proc.kill()
    proc.wait()


@pytest.mark.parametrize("command", list(COMMANDS))
def test_kill_9_at_the_transaction_stages_leaves_old_or_new(command, tmp_path):
    argv, owned = COMMANDS[command]
    outcomes = []
    for i, stage in enumerate([None, owned[0], owned[-1]]):
        parent = tmp_path / f"k{i}"
        parent.mkdir()
        out = setup(parent, owned)
        old = snapshot(out)
        args = [a.format(tmp=parent, out=out) for a in argv]
        proc = subprocess.Popen([sys.executable, "-m", "pushplan.cli", *args], env=ENV, cwd=parent,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        kill_at(proc, staged(parent, stage))
        now = snapshot(out)
        if now == old:
            outcomes.append("old")
        else:  # the new output whole: every owned file new, the user's file carried over
            assert set(now) == set(old), (command, stage, sorted(now))
            assert all(now[k] != old[k] for k in owned) and now["notes.txt"] == old["notes.txt"]
            json.loads((out / owned[0]).read_text()) if owned[0].endswith(".json") else None
            outcomes.append("new")
        assert proc.returncode in (0, -9, 3), (command, stage, proc.returncode)
    assert "old" in outcomes, outcomes
    # the next run repairs and removes what the killed ones left, and completes
    parent = tmp_path / "k2"
    done = main([a.format(tmp=parent, out=parent / "out") for a in argv])
    assert done in (0, 3)
    assert [p.name for p in parent.iterdir() if p.name.startswith(".out.")] == []
    assert all((parent / "out" / k).read_text(errors="replace") != "previous" for k in owned)


def test_a_closed_loop_without_recording_keeps_no_old_recording(tmp_path):
    argv, owned = COMMANDS["closed-loop"]
    out = setup(tmp_path, owned)
    assert main([a.format(tmp=tmp_path, out=out) for a in argv]) in (0, 3)  # 3: outside the tolerance, files written
    assert (out / "recording.rrd").stat().st_size > 100
    assert main([a.format(tmp=tmp_path, out=out) for a in argv] + ["--no-recording"]) in (0, 3)
    assert not (out / "recording.rrd").exists()
    assert (out / "notes.txt").read_text() == "kept across runs"
