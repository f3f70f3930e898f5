"""Process times of the two issue-32 commands as a user runs them, this tree against the
tree before, in one run (issue 32 item 3):

- ``pushplan simulate scenarios/paper_case3.toml --no-recording --out DIR`` (target
  <= 1.2 s wall);
- ``pushplan plan scenarios/plan_steel_case3.toml --out DIR`` (target <= 1.0 s wall);
- and the floors under them, each a process, on every tree: the interpreter with numpy
  and scipy.linalg imported; ``import fe_contact``; the same and the first compiled
  kernel called (the cone projection: before issue 32 item 3 a cached numba kernel,
  whose load, numba's typing context, every FE run paid); ``import rerun``.

Each command is a process started as the installed ``pushplan`` script starts it
(``from pushplan.cli import main``), from the tree's root with the tree's own
``.venv/bin/python`` (this tree's where a tree has none), the thread variables the
Makefile sets and PYTHONDONTWRITEBYTECODE removed (``_common.user_env``); the trees alternate run by run.  This tree runs also through its
installed ``.venv/bin/pushplan``.  Wall time (``perf_counter`` around the process) and
CPU time (user + system of the process and its children, ``RUSAGE_CHILDREN``); medians of
``--repeat`` runs; the load average before and after.  Writes
``benchmarks/results/startup.json``.

    git worktree add ../aot-base d7aea18 && ln -s /path/to/a/venv/with/numba ../aot-base/.venv
    .venv/bin/python benchmarks/startup.py --base ../aot-base [--repeat 5]

``--base``: a checkout of the tree to compare with (its code is imported from its root;
a tree from before the compiled kernels, d7aea18 and older, needs a venv with numba).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import user_env, write_results

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = "import sys\nfrom pushplan.cli import main\nsys.argv[0] = 'pushplan'\nsys.exit(main())\n"
FIRST_KERNEL = ("import numpy as np\nimport fe_contact\nfrom fe_contact.contact.friction import _project\n"
                "_project(np.ones((1, 3)), np.ones(1), np.ones(1))\n")
FLOORS = {
    "python_numpy_scipy_linalg": ["-c", "import numpy, scipy.linalg"],
    "import_fe_contact": ["-c", "import fe_contact"],
    "fe_contact_first_kernel": ["-c", FIRST_KERNEL],
    "import_rerun": ["-c", "import rerun, rerun.blueprint"],
}


def timed(argv: list[str], cwd: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one process, its children included."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, cwd=cwd, env=user_env(), check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def commands(out: Path) -> dict:
    return {
        "simulate": ["simulate", "scenarios/paper_case3.toml", "--no-recording", "--out", str(out / "sim"), "--quiet"],
        "plan": ["plan", "scenarios/plan_steel_case3.toml", "--out", str(out / "plan"), "--quiet"],
    }


def python_of(root: Path) -> str:
    """The tree's own interpreter, or this tree's."""
    own = root / ".venv" / "bin" / "python"
    return str(own if own.exists() else ROOT / ".venv" / "bin" / "python")


def measure(trees: dict[str, Path], repeat: int, tmp: Path) -> dict:
    installed = str(ROOT / ".venv" / "bin" / "pushplan")
    for root in trees.values():  # a numba tree's on-disk cache filled, and the files read once, not timed
        subprocess.run([python_of(root), "-c", "import fe_contact; fe_contact.warm_up()"], cwd=root, env=user_env(),
                       check=True)
    runs: dict = {}
    for _ in range(repeat):
        for name in ("simulate", "plan"):
            for label, root in trees.items():
                argv = commands(tmp / label)[name]
                runs.setdefault(name, {}).setdefault(label, []).append(
                    timed([python_of(root), "-c", SCRIPT, *argv], root))
            argv = commands(tmp / "installed")[name]
            runs[name].setdefault("this_installed", []).append(timed([installed, *argv], ROOT))
        for name, argv in FLOORS.items():
            for label, root in trees.items():
                runs.setdefault(name, {}).setdefault(label, []).append(timed([python_of(root), *argv], root))
    return runs


def summarise(runs: dict) -> dict:
    out = {}
    for name, by_tree in runs.items():
        med = {label: {"wall_s": float(np.median([w for w, _ in r])), "cpu_s": float(np.median([c for _, c in r]))}
               for label, r in by_tree.items()}
        row = {"median": med, "runs": {label: [{"wall_s": w, "cpu_s": c} for w, c in r] for label, r in by_tree.items()}}
        for label in med:
            if label not in ("this", "this_installed") and "this" in med:
                row[f"ratio_this_over_{label}"] = {k: med["this"][k] / med[label][k] for k in ("wall_s", "cpu_s")}
        out[name] = row
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, action="append", default=[],
                        help="checkout of a tree to compare with, labelled by its folder name; may be repeated")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    trees = {"this": ROOT, **{b.resolve().name: b.resolve() for b in args.base}}
    load_before, started = os.getloadavg(), time.strftime("%Y-%m-%d %H:%M")
    with tempfile.TemporaryDirectory() as d:
        runs = measure(trees, args.repeat, Path(d))
    result = {"started": started, "load_average_before": load_before, "load_average_after": os.getloadavg(), "cpus": os.cpu_count(),
              "repeat": args.repeat, "bases": {b.resolve().name: str(b.resolve()) for b in args.base},
              "python_dont_write_bytecode": os.environ.get("PYTHONDONTWRITEBYTECODE", ""),
              "figures": summarise(runs)}
    for name, row in result["figures"].items():
        text = "  ".join(f"{label}: wall {m['wall_s']:.2f} s cpu {m['cpu_s']:.2f} s" for label, m in row["median"].items())
        ratios = "  ".join(f"this/{k[len('ratio_this_over_'):]} wall {r['wall_s']:.3f} cpu {r['cpu_s']:.3f}"
                           for k, r in row.items() if k.startswith("ratio_this_over_"))
        print(f"{name:>26}  {text}  {ratios}")
    print(f"load average {load_before[0]:.2f} -> {result['load_average_after'][0]:.2f} on {os.cpu_count()} cpus; "
          f"medians of {args.repeat}")
    print(f"wrote {write_results('startup', result)}")


if __name__ == "__main__":
    main()
