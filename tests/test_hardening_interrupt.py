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
from pushplan.planning import nlp

at = [0, 0]  # the NLP solve under way (from 1) and ipopt's iteration in it
real_solve, real_nlpsol = nlp._Program.solve, casadi.nlpsol


class Hook(casadi.Callback):  # ipopt's iteration callback: Ctrl-C at iteration {iteration} of solve {solve}
    def __init__(self, sizes):
        casadi.Callback.__init__(self)
        self.sizes = sizes
        self.construct("ctrl_c", {{}})

    def get_n_in(self):
        return casadi.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return casadi.nlpsol_out(i)

    def get_sparsity_in(self, i):
        return casadi.Sparsity.dense(self.sizes[casadi.nlpsol_out(i)], 1)

    def eval(self, arg):
        if at == [{solve}, {iteration}]:
            signal.raise_signal(signal.SIGINT)
        at[1] += 1
        return [0]


def nlpsol(name, plugin, problem, options):
    nx, ng, np_ = (problem[k].numel() for k in ("x", "g", "p"))
    hook = Hook({{"x": nx, "f": 1, "g": ng, "lam_x": nx, "lam_g": ng, "lam_p": np_}})
    solver = real_nlpsol(name, plugin, problem, dict(options, iteration_callback=hook))
    solver.hook = hook  # alive as long as the solver
    return solver


def solve(self, *args):
    at[:] = [at[0] + 1, 0]
    return real_solve(self, *args)


casadi.nlpsol, nlp._Program.solve = nlpsol, solve
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
