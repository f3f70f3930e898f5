"""Wall times as a user sees them (issue 21): each command a process, start to exit,
without the thread variables the Makefile sets.

- ``pushplan --help``;
- ``pushplan simulate scenarios/paper_case3.toml`` and ``pushplan plan
  scenarios/plan_steel_case3.toml`` (and the plan's own ``plan time``);
- the co-simulation rate on 4x4x2 and 8x8x4 (``cosim.json``: periods / loop time,
  start-up apart);
- the same ``simulate`` with ``OPENBLAS_NUM_THREADS`` unset and set to 1 while two other
  CPU-bound processes run (the busy-machine ratio), alternating, medians.

Medians of ``--repeat`` runs; writes ``benchmarks/results/user_times.json``.

    python benchmarks/user_times.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import user_env, write_results

ROOT = Path(__file__).resolve().parents[1]
BURN = "import time\nt = time.time()\nwhile time.time() - t < 600: pass\n"


def timed(argv, env=None) -> tuple[float, str]:
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "pushplan.cli", *argv], capture_output=True, text=True,
                         env=env or user_env(), cwd=ROOT, check=True).stdout
    return time.perf_counter() - t0, out


def median(fn, repeat: int) -> float:
    return float(np.median([fn() for _ in range(repeat)]))


def cosim_rate(elements, tmp: Path) -> dict:
    out = tmp / f"cosim_{elements[0]}"
    timed(["mujoco", "cosim", "scenarios/mujoco_push.toml", "--out", str(out), "--no-rerun",
           "--elements", *map(str, elements)])
    doc = json.loads((out / "cosim.json").read_text())
    return {"elements": list(elements), "periods_per_s": doc["rate_periods_per_s"], "startup_s": doc["startup_s"]}


def busy_ratio(tmp: Path, repeat: int) -> dict:
    burners = [subprocess.Popen([sys.executable, "-c", BURN]) for _ in range(2)]
    try:
        unset, one = [], []
        for _ in range(repeat):
            for env, into in ((user_env(), unset), (user_env(OPENBLAS_NUM_THREADS="1"), one)):
                into.append(timed(["simulate", "scenarios/paper_case3.toml", "--out", str(tmp / "busy"),
                                   "--quiet", "--no-recording"], env)[0])
    finally:
        for b in burners:
            b.kill()
    return {"unset_s": float(np.median(unset)), "one_thread_s": float(np.median(one)),
            "ratio": float(np.median(unset) / np.median(one))}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        result = {"load_average_at_start": os.getloadavg()[0]}
        result["help_s"] = median(lambda: timed(["--help"])[0], args.repeat)
        result["simulate_paper_case3_s"] = median(lambda: timed(
            ["simulate", "scenarios/paper_case3.toml", "--out", str(tmp / "sim"), "--quiet"])[0], args.repeat)
        wall, out = timed(["plan", "scenarios/plan_steel_case3.toml", "--out", str(tmp / "plan"), "--quiet"])
        result["plan_steel_case3"] = {"process_s": wall,
                                      "plan_time_s": float(re.search(r"plan time ([\d.]+) s", out).group(1))}
        result["cosim"] = [cosim_rate(e, tmp) for e in ((4, 4, 2), (8, 8, 4))]
        result["busy_machine"] = busy_ratio(tmp, args.repeat)
    print(json.dumps(result, indent=2))
    print(f"wrote {write_results('user_times', result)}")


if __name__ == "__main__":
    main()
