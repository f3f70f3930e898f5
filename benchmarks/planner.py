"""Planner on the full planning scenarios: plan time, FE rollouts, FE-verified final
error of the plan and of the naive straight push (issue 5 acceptance).

    python benchmarks/planner.py [--scenarios plan_steel_case3 plan_yaw ...]

Prints a table and writes ``benchmarks/results/planner.json``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from _common import write_results
from pushplan.planning import plan, plan_document
from pushplan.config import load_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
PLANNING_SCENARIOS = ("plan_steel_case3", "plan_rubber", "plan_rotated_axes", "plan_yaw")
ACCEPT_POSITION_REL = 0.01
ACCEPT_YAW_DEG = 0.5
ACCEPT_NAIVE_RATIO = 10.0


def acceptance(doc: dict) -> dict:
    """Issue 5 criteria on one plan document."""
    err, naive = doc["final_error"], doc["naive"]["final_error"]
    ok_pos = err["position_rel_travel"] <= ACCEPT_POSITION_REL
    ok_yaw = err["yaw_deg"] is None or err["yaw_deg"] <= ACCEPT_YAW_DEG
    needs_ratio = naive["position_rel_travel"] > ACCEPT_POSITION_REL
    ratio = naive["position"] / err["position"] if err["position"] > 0 else math.inf
    ok_ratio = not needs_ratio or ratio >= ACCEPT_NAIVE_RATIO
    return {"position": ok_pos, "yaw": ok_yaw, "naive_ratio": ratio, "naive_ratio_ok": ok_ratio,
            "passed": bool(ok_pos and ok_yaw and ok_ratio and doc["status"] == "converged")}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=list(PLANNING_SCENARIOS))
    args = parser.parse_args(argv)
    rows = {}
    print(f"{'scenario':<20} {'status':<10} {'plan s':>7} {'FE rollouts':>11} {'error':>18} {'naive':>18} "
          f"{'ratio':>8} {'yaw err':>8} {'naive yaw':>9}")
    for name in args.scenarios:
        scenario = load_scenario(SCENARIOS / f"{name}.toml")
        t0 = time.perf_counter()
        result = plan(scenario)
        wall = time.perf_counter() - t0
        doc = plan_document(result)
        acc = acceptance(doc)
        err, naive = doc["final_error"], doc["naive"]["final_error"]
        rollouts = doc["solver"]["fe_rollouts"]
        rows[name] = {
            "status": doc["status"], "plan_time_s": wall, "wall_time_s": doc["solver"]["wall_time_s"],
            "fe_rollouts": rollouts, "nlp_solves": doc["solver"]["nlp_solves"],
            "travel": doc["plan"]["travel"], "final_error": err, "naive_final_error": naive,
            "meshes": doc["meshes"], "reduced_model": doc["reduced_model"], "acceptance": acc,
            "iterations": doc["solver"]["iterations"],
        }
        yaw = f"{err['yaw_deg']:.4f}" if err["yaw_deg"] is not None else "-"
        nyaw = f"{naive['yaw_deg']:.4f}" if naive["yaw_deg"] is not None else "-"
        print(f"{name:<20} {doc['status']:<10} {wall:>7.1f} {rollouts['planning']:>5} + {rollouts['verification']:<3}"
              f" {err['position'] * 1e6:>8.3f} um {100 * err['position_rel_travel']:>5.3f}%"
              f" {naive['position'] * 1e6:>8.2f} um {100 * naive['position_rel_travel']:>5.2f}%"
              f" {acc['naive_ratio']:>8.0f} {yaw:>8} {nyaw:>9}", flush=True)
    payload = {"scenarios": rows, "all_passed": all(r["acceptance"]["passed"] for r in rows.values())}
    path = write_results("planner", payload)
    print(f"acceptance: {'all passed' if payload['all_passed'] else 'FAILED'}; wrote {path}")
    return payload


if __name__ == "__main__":
    main()
