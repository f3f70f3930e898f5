"""The fixed per-run costs issue 32 took out of ``pushplan simulate`` / ``pushplan plan``,
each measured in this tree and in the tree before, in one run (the whole commands'
process times: ``benchmarks/startup.py``):

- ``model_build``: ``Scenario.model()`` of the paper case (20x20x5, 27 Gauss points; the
  element geometry's Jacobians and gradients), the first call in a process and the median
  of the next five;
- ``stored_energy``: the strain energy every step's report holds, 20x20x5, median of 20;
- ``recording_mesh``: what ``pushplan plan`` builds for its recording, 12x12x4: a second
  ``Model`` before, the mesh alone now;
- ``solve_phase_paper_case``: the "solve" phase (``StepReport.timings``) of the paper case's five
  steps with single right-hand sides through ``dtrsv`` against ``dtrsm`` (both in this tree's
  process, whole runs alternating: one change measured alone);
- ``recording_wait``: how long ``pushplan plan scenarios/plan_steel_case3.toml`` waits
  at its end for the recording process (the job's time in a child that imported rerun
  while the parent planned; warmed up now), in-process ``main``, median of ``--repeat``;
- ``exit_after_simulate``: from the end of ``main`` (a paper-case simulate) to the end of
  its process: the interpreter's shutdown, whose full garbage collection the CLI now skips
  (``gc.freeze`` at exit), median of ``--repeat``;
- ``simulate_busy``: process wall time of ``pushplan simulate scenarios/paper_case3.toml
  --no-recording`` as a user runs it (thread variables unset) while one CPU-bound process
  runs on the 2-core machine; the trees alternate (dense-kernel threads: the CPUs idle
  now, not by the lagging load average alone).

Each tree's code is imported from its root by a child process, so this tree's ``.venv``
serves both (see ``benchmarks/startup.py``)::

    git worktree add ../cold-base d7aea18 && ln -s "$PWD/.venv" ../cold-base/.venv
    .venv/bin/python benchmarks/fixed_costs.py --base ../cold-base [--repeat 3]

Writes ``benchmarks/results/fixed_costs.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import user_env, write_results

ROOT = Path(__file__).resolve().parents[1]
BURN = "import time\nt = time.time()\nwhile time.time() - t < 600: pass\n"

COMPONENTS = r'''
import json, sys, tempfile, time
import numpy as np
from pushplan.config import load_scenario
from fe_contact.fem.elasticity import stored_energy

def median(f, n):
    times = []
    for _ in range(n):
        t = time.perf_counter(); f(); times.append(time.perf_counter() - t)
    return float(np.median(times))

out = {}
paper = load_scenario("scenarios/paper_case3.toml")
t = time.perf_counter(); model = paper.model(); out["model_build_first_s"] = time.perf_counter() - t
out["model_build_s"] = median(paper.model, 5)
U = 1e-5 * np.random.default_rng(0).standard_normal((model.mesh.n_nodes, 3))
out["stored_energy_s"] = median(lambda: stored_energy(model.geometry, model.mesh.elements, U, model.material), 20)
steel = load_scenario("scenarios/plan_steel_case3.toml")
out["recording_mesh_s"] = median(steel.mesh if hasattr(steel, "mesh") else steel.model, 5)

import fe_contact.linalg.cholesky as ch
if hasattr(ch, "_triangular_solve"):  # this tree: its solves against dtrsm's, whole runs alternating
    from scipy.linalg import blas
    from fe_contact import initial_state, step
    trsv = ch._triangular_solve
    def trsm(L, b, transposed=False):
        return blas.dtrsm(1.0, L, b, lower=1, trans_a=int(transposed))
    phases = {"dtrsv": [], "dtrsm": []}
    for r in range(4):
        for name in (("dtrsv", "dtrsm") if r % 2 == 0 else ("dtrsm", "dtrsv")):
            ch._triangular_solve = trsv if name == "dtrsv" else trsm
            state, total = initial_state(model), 0.0
            for c in paper.commands:
                state, rep = step(model, state, c, consume=True)
                total += rep.timings["solve"]
            phases[name].append(total)
    ch._triangular_solve = trsv
    out["solve_phase_dtrsv_s"] = float(np.median(phases["dtrsv"]))
    out["solve_phase_dtrsm_s"] = float(np.median(phases["dtrsm"]))

import pushplan.outputs.recording_process as rp
waits = []
run = rp.RecordingProcess.run
def timed_run(self, fn, *args):
    t = time.perf_counter(); run(self, fn, *args); waits.append(time.perf_counter() - t)
rp.RecordingProcess.run = timed_run
from pushplan.cli import main
for _ in range(int(sys.argv[1])):
    with tempfile.TemporaryDirectory() as d:
        assert main(["plan", "scenarios/plan_steel_case3.toml", "--out", d, "--quiet"]) == 0
out["recording_wait_s"] = float(np.median(waits))
out["recording_waits_s"] = waits
print(json.dumps(out))
'''


def components(root: Path, repeat: int) -> dict:
    python = str(ROOT / ".venv" / "bin" / "python")
    out = subprocess.run([python, "-c", COMPONENTS, str(repeat)], cwd=root, env=user_env(), check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


EXIT = ("import sys, time\nfrom pushplan.cli import main\nstatus = main(sys.argv[1:])\n"
        "print(repr(time.time()), flush=True)\nsys.exit(status)\n")


def exit_times(trees: dict, repeat: int, tmp: Path) -> dict:
    """Seconds from the end of ``main`` (a paper-case simulate) to the end of its process
    (the interpreter's shutdown), per tree, the trees alternating."""
    python = str(ROOT / ".venv" / "bin" / "python")
    times: dict = {label: [] for label in trees}
    for _ in range(repeat):
        for label, root in trees.items():
            argv = [python, "-c", EXIT, "simulate", "scenarios/paper_case3.toml", "--no-recording", "--out",
                    str(tmp / label), "--quiet"]
            out = subprocess.run(argv, cwd=root, env=user_env(), check=True, capture_output=True, text=True)
            times[label].append(time.time() - float(out.stdout.strip().splitlines()[-1]))
    return {label: float(np.median(t)) for label, t in times.items()}


def simulate_busy(trees: dict, repeat: int, tmp: Path) -> dict:
    """Process wall times of simulate per tree with one CPU-bound process running."""
    python = str(ROOT / ".venv" / "bin" / "python")
    script = "import sys\nfrom pushplan.cli import main\nsys.exit(main())\n"
    walls: dict = {label: [] for label in trees}
    burner = subprocess.Popen([sys.executable, "-c", BURN])
    try:
        time.sleep(1.0)
        for _ in range(repeat):
            for label, root in trees.items():
                argv = [python, "-c", script, "simulate", "scenarios/paper_case3.toml", "--no-recording",
                        "--out", str(tmp / label), "--quiet"]
                t = time.perf_counter()
                subprocess.run(argv, cwd=root, env=user_env(), check=True)
                walls[label].append(time.perf_counter() - t)
    finally:
        burner.kill()
        burner.wait()
    return {label: {"median_s": float(np.median(w)), "runs_s": w} for label, w in walls.items()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="checkout of the tree to compare with")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    trees = {"this": ROOT, "base": args.base.resolve()}
    load_before, started = os.getloadavg(), time.strftime("%Y-%m-%d %H:%M")
    for root in trees.values():  # numba's on-disk cache of each tree filled, not timed
        subprocess.run([str(ROOT / ".venv" / "bin" / "python"), "-c", "import fe_contact; fe_contact.warm_up()"],
                       cwd=root, env=user_env(), check=True)
    measured = {label: components(root, args.repeat) for label, root in trees.items()}
    with tempfile.TemporaryDirectory() as d:
        exits = exit_times(trees, args.repeat, Path(d))
        busy = simulate_busy(trees, args.repeat, Path(d))
    rows = {}
    for key in ("model_build_first_s", "model_build_s", "stored_energy_s", "recording_mesh_s", "recording_wait_s"):
        this, base = measured["this"][key], measured["base"][key]
        rows[key] = {"this": this, "base": base, "saved_s": base - this, "ratio_this_over_base": this / base}
    rows["exit_after_simulate_s"] = {**exits, "saved_s": exits["base"] - exits["this"],
                                     "ratio_this_over_base": exits["this"] / exits["base"]}
    this = measured["this"]
    if "solve_phase_dtrsv_s" in this:  # one change, A/B in this tree's process
        rows["solve_phase_paper_case_s"] = {
            "this": this["solve_phase_dtrsv_s"], "base": this["solve_phase_dtrsm_s"],
            "saved_s": this["solve_phase_dtrsm_s"] - this["solve_phase_dtrsv_s"],
            "ratio_this_over_base": this["solve_phase_dtrsv_s"] / this["solve_phase_dtrsm_s"]}
    rows["simulate_busy_wall_s"] = {**{k: v["median_s"] for k, v in busy.items()},
                                    "ratio_this_over_base": busy["this"]["median_s"] / busy["base"]["median_s"]}
    result = {"started": started, "load_average_before": load_before, "load_average_after": os.getloadavg(),
              "repeat": args.repeat, "base": str(trees["base"]), "figures": rows, "raw": measured, "busy": busy}
    for key, row in rows.items():
        print(f"{key:>22}  this {row['this'] * 1e3:9.1f} ms  base {row['base'] * 1e3:9.1f} ms  "
              f"this/base {row['ratio_this_over_base']:.3f}")
    print(f"load average {load_before[0]:.2f} -> {result['load_average_after'][0]:.2f} on {os.cpu_count()} cpus")
    print(f"wrote {write_results('fixed_costs', result)}")


if __name__ == "__main__":
    main()
