"""The figures of issue 32 ("fast enough to sit inside a robot's control loop"), this
tree against the tree before, in one run, alternating A and B:

- ``pushplan simulate scenarios/paper_case3.toml --no-recording``: process wall and CPU time;
- ``pushplan plan scenarios/plan_steel_case3.toml`` (with its recording) and, on this
  tree, the same with ``--no-baseline``;
- ``pushplan plan scenarios/plan_rubber.toml --no-recording``: a whole plan on the
  rubber scenario; and a re-plan of it ``--from`` the observations of the press and the
  first two planned pushes (what the closed loop does at each push, cold: a process per
  re-plan), on this tree also with ``--no-baseline`` as ``closed-loop`` now re-plans (the
  warm re-plan of issue 32 is not measured here);
- co-simulation over ``--periods`` periods (``run_cosimulation`` of ``mujoco_push`` with a
  press and ``periods - 1`` pushes) on 4x4x2 and 8x8x4: periods per second of the loop,
  by wall clock and by the process's CPU time (the machine is shared: the CPU rate is
  what a quiet core would give).

Processes run as a user runs them: ``python -m pushplan.cli`` from the tree's root, the
thread variables the Makefile sets and PYTHONDONTWRITEBYTECODE removed (``_common.user_env``).  The load average is recorded before and
after.  Writes ``benchmarks/results/loop_times.json``.

    python benchmarks/loop_times.py --base ../perf-base [--base ../perf-main] [--repeat 3] [--periods 100]

``--base``: a checkout of a tree to compare with (the tree before, commit 7a78d0d; main)
with its own ``.venv`` (``make .venv/.installed`` there); ratios are this tree's medians
over its.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import user_env, write_results

ROOT = Path(__file__).resolve().parents[1]

COSIM_CHILD = """
import json, math, sys, time
from fe_contact import Command, warm_up
from pushplan.mujoco.cosim import run_cosimulation
from pushplan.mujoco.scene import open_scene
periods, elements = int(sys.argv[1]), tuple(int(v) for v in sys.argv[2:5])
scene, _ = open_scene("scenarios/mujoco_push.toml")
step = 4 * 0.32e-3 / (periods - 1) / math.sqrt(2.0)
commands = [Command(dz=-1e-4)] + [Command(dx=step, dy=step)] * (periods - 1)
model = scene.scenario.model(elements=elements, quadrature=2)
warm_up()
c0 = time.process_time()
warm_up()  # run_cosimulation calls it again before its loop: its CPU time is taken off below
c1 = time.process_time()
record = run_cosimulation(scene, commands, fe_model=model)
loop_cpu = time.process_time() - c1 - (c1 - c0)
assert record.status.value == "completed", record.status
print(json.dumps({"periods": len(record.periods), "loop_wall_s": record.wall_s, "rate_wall": record.rate_periods_per_s,
                  "loop_cpu_s": loop_cpu, "rate_cpu": len(record.periods) / loop_cpu}))
"""


class Tree:
    """A source tree with its ``.venv``: runs ``python -m pushplan.cli`` from its root."""

    def __init__(self, label: str, root: Path):
        self.label, self.root = label, root
        self.python = root / ".venv" / "bin" / "python"
        if not self.python.exists():
            raise SystemExit(f"{self.python} not found: make .venv/.installed in {root}")

    def run(self, argv: list[str]) -> tuple[float, float, str]:
        """(wall s, CPU s of the process, stdout)."""
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        out = subprocess.run([str(self.python), *argv], capture_output=True, text=True, env=user_env(),
                             cwd=self.root, check=True).stdout
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return wall, cpu, out


def observations(tree: Tree, tmp: Path) -> Path:
    """``obs.csv``: the press and the first two pushes of the rubber plan, executed."""
    cli = ["-m", "pushplan.cli"]
    tree.run([*cli, "plan", "scenarios/plan_rubber.toml", "--out", str(tmp / "p0"), "--quiet", "--no-recording"])
    first = json.loads((tmp / "p0" / "plan.json").read_text())
    (tmp / "executed.json").write_text(json.dumps({"commands": first["commands"][:3]}))
    tree.run([*cli, "simulate", "scenarios/plan_rubber.toml", "--commands", str(tmp / "executed.json"), "--out",
              str(tmp / "s"), "--quiet", "--no-recording", "--observations", str(tmp / "obs.csv")])
    return tmp / "obs.csv"


def figures(tmp: Path, periods: int, new: bool) -> dict:
    """name -> argv; ``new``: the options only this tree has."""
    cli = ["-m", "pushplan.cli"]
    out = dict(
        simulate=[*cli, "simulate", "scenarios/paper_case3.toml", "--out", str(tmp / "sim"), "--quiet",
                  "--no-recording"],
        plan_steel_case3=[*cli, "plan", "scenarios/plan_steel_case3.toml", "--out", str(tmp / "plan"), "--quiet"],
        plan_rubber=[*cli, "plan", "scenarios/plan_rubber.toml", "--out", str(tmp / "rubber"), "--quiet",
                     "--no-recording"],
        replan_rubber=[*cli, "plan", "scenarios/plan_rubber.toml", "--from", str(tmp.parent / "obs.csv"), "--out",
                       str(tmp / "replan"), "--quiet", "--no-recording"],
        cosim_4x4x2=["-c", COSIM_CHILD, str(periods), "4", "4", "2"],
        cosim_8x8x4=["-c", COSIM_CHILD, str(periods), "8", "8", "4"],
    )
    if new:
        out["plan_steel_case3_no_baseline"] = [*out["plan_steel_case3"], "--no-baseline"]
        out["replan_rubber_no_baseline"] = [*out["replan_rubber"], "--no-baseline"]
    return out


def measure(trees: list[Tree], repeat: int, periods: int, tmp: Path) -> dict:
    for tree in trees:  # numba's on-disk cache of each tree filled (a first run compiles), not timed
        tree.run(["-c", "import fe_contact; fe_contact.warm_up()"])
    observations(trees[0], tmp)
    samples: dict = {}
    for _ in range(repeat):
        for name in figures(tmp, periods, True):
            for tree in trees:  # alternating A and B, figure by figure
                argv = figures(tmp / tree.label, periods, tree is trees[0]).get(name)
                if argv is None:
                    continue
                (tmp / tree.label).mkdir(exist_ok=True)
                wall, cpu, out = tree.run(argv)
                entry = {"wall_s": wall, "cpu_s": cpu}
                if name.startswith("cosim"):
                    entry.update(json.loads(out.strip().splitlines()[-1]))
                samples.setdefault(name, {}).setdefault(tree.label, []).append(entry)
    return samples


def summarise(samples: dict) -> dict:
    """Medians per figure and tree, and the ratios of this tree's medians over each other's."""
    result = {}
    for name, by_tree in samples.items():
        med = {label: {k: float(np.median([s[k] for s in runs])) for k in runs[0]} for label, runs in by_tree.items()}
        row = {"median": med, "runs": by_tree}
        key = ("rate_wall", "rate_cpu") if name.startswith("cosim") else ("wall_s", "cpu_s")
        for label in med:
            if label != "this" and "this" in med:
                row[f"ratio_this_over_{label}"] = {k: med["this"][k] / med[label][k] for k in key}
        result[name] = row
    return result


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, action="append", default=[],
                        help="checkout of a tree to compare with (its .venv), labelled by its folder name; "
                        "may be repeated")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--periods", type=int, default=100)
    args = parser.parse_args(argv)
    trees = [Tree("this", ROOT)] + [Tree(b.resolve().name, b.resolve()) for b in args.base]
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        samples = measure(trees, args.repeat, args.periods, Path(d))
    result = {"load_average_before": load_before, "load_average_after": os.getloadavg(),
              "cpus": os.cpu_count(), "repeat": args.repeat, "periods": args.periods,
              "bases": {b.resolve().name: str(b.resolve()) for b in args.base}, "figures": summarise(samples)}
    for name, row in result["figures"].items():
        med = row["median"]
        text = "  ".join(f"{label}: wall {m['wall_s']:.2f} s cpu {m['cpu_s']:.2f} s"
                         + (f" ({m['rate_wall']:.0f} periods/s wall, {m['rate_cpu']:.0f} cpu)" if "rate_cpu" in m
                            else "") for label, m in med.items())
        ratios = "  ".join(f"this/{k[len('ratio_this_over_'):]} " + ", ".join(f"{q} {v:.3f}" for q, v in r.items())
                           for k, r in row.items() if k.startswith("ratio_this_over_"))
        print(f"{name:>30}  {text}  {ratios}")
    print(f"load average {load_before[0]:.1f} -> {result['load_average_after'][0]:.1f} on {os.cpu_count()} cpus")
    print(f"wrote {write_results('loop_times', result)}")


if __name__ == "__main__":
    main()
