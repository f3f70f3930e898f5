"""Robust re-plans in the closed loop (issue 42 item 4): ``closed-loop --identify`` with and
without a ``[plan] robust`` table on the same truth, for the steel case of
``tests/test_closed_loop.py`` (friction 30 % above the model's) and the shipped
``scenarios/plan_robust.toml`` (its truth's mu_y 0.17 against the model's 0.15), and the rest
target with a frictional pad of ``tests/test_episodes.py`` (pad 0.9, the truth's floor +25 %,
Young +20 %, on a finer mesh).  Per re-plan
the predicted probability of the robust re-plan and of the nominal one beside it, the
parameters held at the estimate, the sigma-point FE rollouts; per loop the final error and
the process wall and CPU time.

    python benchmarks/robust_loop.py

Writes ``benchmarks/results/robust_loop.json``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
import tomllib
from pathlib import Path

from _common import write_results
from pushplan.config import load_scenario, parse_scenario
from pushplan.config.plan import parse_plan
from pushplan.identify.closed_loop import closed_loop

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_closed_loop import MODEL, PLAN  # noqa: E402
from test_episodes import BLOCK, REST_PLAN  # noqa: E402

ROBUST = "robust = {level = 0.9, max_iterations = 4, monte_carlo = 0}\n"


def cases():
    """``(name, model with the robust table, truth)`` scenarios."""
    steel = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.3, mu_y=0.15) + PLAN + ROBUST))
    steel_truth = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.39, mu_y=0.195)))
    shipped = load_scenario(ROOT / "scenarios" / "plan_robust.toml")
    shipped_truth = dataclasses.replace(shipped, mu_y=0.17, name="plan_robust_truth")
    pad = parse_scenario(tomllib.loads('name = "m"' + BLOCK.format(elements=[3, 2, 2], young=2e6, mu_x=0.6, mu_y=0.25,
                                                                  pad="0.9") + REST_PLAN + ROBUST))
    pad_truth = parse_scenario(tomllib.loads('name = "t"' + BLOCK.format(elements=[4, 3, 2], young=2.4e6, mu_x=0.75,
                                                                        mu_y=0.3125, pad="0.9")))
    return [("steel, friction +30 %", steel, steel_truth), ("plan_robust, mu_y 0.17", shipped, shipped_truth),
            ("rest target, pad 0.9, floor +25 %, Young +20 %, finer truth", pad, pad_truth)]


def one(model, truth, robust: bool) -> dict:
    spec = parse_plan(model)
    t0, c0 = time.perf_counter(), time.process_time()
    result = closed_loop(model, truth, spec, use_identify=True, robust=robust)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    doc = result.to_dict()
    return {"robust": robust, "final_error": doc["closed_loop"]["final_error"],
            "open_loop_error": doc["open_loop"]["final_error"], "tolerance": spec.tolerance,
            "replans": [it["robust"] for it in doc["iterations"]], "wall_s": wall, "cpu_s": cpu}


def main() -> None:
    rows = []
    for name, model, truth in cases():
        loops = [one(model, truth, r) for r in (False, True)]
        rows.append({"case": name, "loops": loops})
        for lp in loops:
            probs = [None if r is None else round(r["predicted_probability"], 4) for r in lp["replans"]]
            print(f"{name}: {'robust ' if lp['robust'] else 'nominal'} closed loop "
                  f"{lp['final_error']['position'] * 1e6:.3f} um (tolerance {lp['tolerance'] * 1e6:.3g} um), "
                  f"predicted per re-plan {probs}, {lp['wall_s']:.1f} s wall, {lp['cpu_s']:.1f} s CPU")
    print(write_results("robust_loop", {"rows": rows}))


if __name__ == "__main__":
    main()
