"""Newton iterations per step and CPU time with Anderson acceleration of the
modified-Newton loop (issue 32, ``SolverOptions.acceleration``), this tree against
another (``--base``: a checkout of main with the same venv's packages) in one run,
alternating the trees, and on this tree with the acceleration off
(``acceleration = 0``).

Cases: the paper's cases 1-3 (20 x 20 x 5, 27 Gauss points; press and 4 pushes);
a Neo-Hookean rubber and a hyperfoam block (press and 4 pushes at 30 deg); a
frictional pad (``tests/test_pad.py``'s block: full Newton, where the acceleration
does nothing); and whole plans, ``pushplan plan scenarios/plan_rubber.toml`` and
``plan_steel_case3.toml`` (every rollout of the planner on its planning mesh; the
Newton iterations summed over every step of the process).

Each figure is a child process (``python -c`` in the tree's root, so the tree's
packages are imported; thread variables set to one thread); CPU time is the child's
own, of the stepping (model build excluded; each step's too) or of the whole plan.
Medians of ``--repeat`` runs (every run's CPU kept in the JSON).  Writes ``benchmarks/results/newton_acceleration.json``.

    python benchmarks/newton_acceleration.py [--base /tmp/main-checkout] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from _common import write_results

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import dataclasses, json, math, sys, time
import numpy as np
import fe_contact
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, run
case, acceleration = sys.argv[1], sys.argv[2]
has = "acceleration" in SolverOptions.__dataclass_fields__
extra = {} if acceleration == "default" or not has else {"acceleration": int(acceleration)}

def pushes(model, press, push, angle, n=4):
    a = math.radians(angle)
    return [Command(dz=-press)] + [Command(dx=push * math.cos(a), dy=push * math.sin(a))] * n

def stepping(model, commands):
    fe_contact.warm_up()
    state, reports, cpu = fe_contact.initial_state(model), [], []
    for command in commands:
        c0 = time.process_time()
        state, report = fe_contact.step(model, state, command, consume=True)
        cpu.append(time.process_time() - c0)
        reports.append(report)
        assert report.converged, report.message
    return {"iterations": [r.newton_iterations for r in reports], "cpu_s": sum(cpu), "cpu_steps_s": cpu,
            "twist_deg": math.degrees(reports[-1].twist), "lower_centroid": reports[-1].lower_centroid.tolist()}

def plan(name, tmp):
    from fe_contact.stepping import held
    from pushplan.cli import main
    count = [0]
    real = held.equilibrium
    def counted(*args, **kw):
        eq = real(*args, **kw)
        count[0] += len(eq.iterations)
        return eq
    held.equilibrium = counted
    scenario = f"scenarios/{name}.toml"
    if extra:
        text = open(scenario).read()
        scenario = f"{tmp}/{name}.toml"
        solver = f"[solver]\nacceleration = {extra['acceleration']}\n"
        text = text.replace("[solver]\n", solver) if "[solver]\n" in text else text + "\n" + solver
        open(scenario, "w").write(text)
    c0 = time.process_time()
    status = main(["plan", scenario, "--out", f"{tmp}/out", "--quiet", "--no-recording"])
    cpu = time.process_time() - c0
    assert status in (0, None), status
    doc = json.load(open(f"{tmp}/out/plan.json"))
    return {"iterations": [count[0]], "cpu_s": cpu, "final_error_m": doc.get("final_error")}

options = SolverOptions(**extra)
if case.startswith("paper_case"):
    from pushplan.config import load_scenario
    sc = load_scenario(f"scenarios/{case}.toml")
    model = sc.model()
    model = dataclasses.replace(model, options=dataclasses.replace(model.options, **extra))
    out = stepping(model, list(sc.commands))
elif case in ("neo_hookean", "hyperfoam"):
    young, poisson = (5e6, 0.45) if case == "neo_hookean" else (0.5e6, 0.0)
    model = Model(block_mesh((0.02, 0.02, 0.01), (10, 10, 4)), Material(young, poisson, model=case),
                  Friction(0.8, 0.3, math.radians(20.0)), quadrature=2, options=options)
    out = stepping(model, pushes(model, 0.5e-3, 0.4e-3, 30.0))
elif case == "pad":
    model = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0),
                  Friction(0.6, 0.2, math.radians(20.0)), quadrature=2, pad=Friction(0.6, 0.2, math.radians(20.0)),
                  options=options)
    out = stepping(model, [Command(dz=-4e-4)] + [Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))] * 2)
else:
    out = plan(case, sys.argv[3])
print(json.dumps(out))
"""

CASES = ("paper_case1", "paper_case2", "paper_case3", "neo_hookean", "hyperfoam", "pad", "plan_rubber",
         "plan_steel_case3")


def child(root: Path, case: str, acceleration: str, tmp: Path) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1"}
    tmp.mkdir(parents=True, exist_ok=True)
    out = subprocess.run([sys.executable, "-c", CHILD, case, acceleration, str(tmp)], cwd=root, env=env,
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{case} in {root} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, default=None, help="checkout of the tree to compare with (main)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=CASES)
    args = parser.parse_args(argv)
    variants = [("this", ROOT, "default"), ("this_off", ROOT, "0")]
    if args.base is not None:
        variants.append(("base", args.base.resolve(), "default"))
    load_before = os.getloadavg()
    runs: dict = {}
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.repeat):
            for case in args.cases:
                for label, root, acceleration in variants:  # alternating, case by case
                    result = child(root, case, acceleration, Path(d) / f"{label}_{case}_{k}")
                    runs.setdefault(case, {}).setdefault(label, []).append(result)
    figures = {}
    for case, by_variant in runs.items():
        row = {}
        for label, results in by_variant.items():
            row[label] = {"iterations": results[0]["iterations"], "total_iterations": sum(results[0]["iterations"]),
                          "cpu_s": float(np.median([r["cpu_s"] for r in results])),
                          "cpu_runs_s": [r["cpu_s"] for r in results],
                          **{k: v for k, v in results[0].items() if k not in ("iterations", "cpu_s", "cpu_steps_s")}}
            if "cpu_steps_s" in results[0]:  # medians step by step
                row[label]["cpu_steps_s"] = np.median([r["cpu_steps_s"] for r in results], axis=0).tolist()
        for other in ("this_off", "base"):
            if other in row:
                row[f"iterations_this_over_{other}"] = row["this"]["total_iterations"] / row[other]["total_iterations"]
                row[f"cpu_this_over_{other}"] = row["this"]["cpu_s"] / row[other]["cpu_s"]
        figures[case] = row
        text = "  ".join(f"{label}: {row[label]['iterations']} = {row[label]['total_iterations']} it, "
                         f"{row[label]['cpu_s']:.3f} s"
                         + (f" (steps 2-: {sum(row[label]['cpu_steps_s'][1:]):.3f} s)" if "cpu_steps_s" in row[label]
                            else "") for label in by_variant)
        print(f"{case:>17}  {text}")
    result = {"load_average_before": load_before, "load_average_after": os.getloadavg(), "repeat": args.repeat,
              "base": None if args.base is None else str(args.base.resolve()), "figures": figures}
    print(f"load average {load_before[0]:.1f} -> {result['load_average_after'][0]:.1f} on {os.cpu_count()} cpus")
    print(f"wrote {write_results('newton_acceleration', result)}")


if __name__ == "__main__":
    main()
