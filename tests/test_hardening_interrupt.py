"""Issue 45: Ctrl-C is exit 130 with the old output whole, at any moment of a plan.

Deterministic: the SIGINT is raised by a hook at a chosen moment (inside ipopt's
iteration callback of the k-th NLP solve; in the recording child right after the fork),
never by a timer."""

import os
import signal
import threading
import subprocess
import sys
from pathlib import Path

import pytest

from pushplan.outputs.recording_process import RecordingProcess

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1"}

INSIDE_THE_NLP = """
import signal, sys
import casadi
from pushplan.cli import main

solves = [0]
real_solve = casadi.Opti.solve

def solve(self):
    solves[0] += 1
    if solves[0] == {solve}:  # Ctrl-C at ipopt's iteration {iteration} of this solve
        self.callback(lambda i: signal.raise_signal(signal.SIGINT) if i == {iteration} else None)
    return real_solve(self)

casadi.Opti.solve = solve
sys.exit(main(sys.argv[1:]))
"""


def snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("solve, iteration", [(1, 0), (1, 3), (2, 1)])
def test_ctrl_c_inside_the_nlp_is_exit_130_with_the_old_output_whole(tmp_path, solve, iteration):
    out = tmp_path / "out"
    old = subprocess.run([sys.executable, "-m", "pushplan.cli", "plan", str(SCENARIOS / "plan_steel_case3.toml"),
                          "--out", str(out), "--quiet", "--no-recording"], env=ENV, capture_output=True, text=True,
                         timeout=300)
    assert old.returncode == 0, old.stderr
    before = snapshot(out)
    proc = subprocess.run([sys.executable, "-c", INSIDE_THE_NLP.format(solve=solve, iteration=iteration), "plan",
                           str(SCENARIOS / "plan_steel_case3.toml"), "--out", str(out), "--quiet"], env=ENV,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.strip().splitlines() == ["pushplan: interrupted"], proc.stderr
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no partial folder, no lock left


def _write(path):
    Path(path).write_text("done")


def test_ctrl_c_reaching_the_recording_child_at_its_start_is_ignored_there(tmp_path, monkeypatch):
    """The SIGINT of a Ctrl-C goes to the whole process group: the child gets it at its
    first instruction after the fork and must go on to do its job (the parent decides)."""
    real_fork = os.fork

    def fork():
        pid = real_fork()
        if pid == 0:
            try:
                os.kill(os.getpid(), signal.SIGINT)
            except KeyboardInterrupt:  # the child interrupted: what the fix prevents
                os._exit(1)
        return pid

    monkeypatch.setattr(os, "fork", fork)
    with RecordingProcess() as writer:
        writer.run(_write, tmp_path / "x")
    assert (tmp_path / "x").read_text() == "done"


def test_ctrl_c_in_the_parent_during_the_fork_is_raised_after_it_and_ends_the_child(monkeypatch):
    real_fork = os.fork
    children = []

    def fork():
        pid = real_fork()
        if pid:
            children.append(pid)
            # to this thread: the mask that holds SIGINT back is per thread, and the test process
            # (an xdist worker) has other threads, which a process-directed signal may reach
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)  # held back until the fork is complete
        return pid

    monkeypatch.setattr(os, "fork", fork)
    with pytest.raises(KeyboardInterrupt):
        with RecordingProcess():
            pytest.fail("the interrupt must come before the block")
    with pytest.raises(ChildProcessError):  # already reaped by the RecordingProcess
        os.waitpid(children[0], os.WNOHANG)
