"""The warm re-plan of the closed loop (issue 32 items 1-2) and the planner's two FE
corrections (issue 30 item 4), in one process, one run:

- ``replan``: ``closed_loop`` of ``plan_rubber`` (the model) on a truth with friction
  ``--truth-friction`` times the model's (0.8 by default: at 1.3 the truth's St
  Venant-Kirchhoff block loses stability in the last push).  Every re-plan of the loop is
  timed warm (what ``closed-loop`` runs: :class:`PlanSession` on the planning mesh 6 x 6 x
  2, quadrature 2) and, on the same observations and shifted target, cold as the loop ran
  before (:func:`replan` from the press: both meshes, calibration, NLP build) and cold on
  the planning mesh alone (the same work as the warm re-plan without what it keeps).
  Medians over the pushes, per re-plan wall and process CPU time; the ratios.
- ``closed_loop``: the whole loop of ``replan`` warm and cold (``closed_loop(...,
  warm=False)``), ``--repeat`` times alternating: wall and CPU time, final error.
- ``refinement``: ``plan`` of plan_steel_case3, plan_rubber and plan_yaw (a yaw target)
  with ``refinement = "modifier"`` and ``"exact_gradient"``, alternating, ``--repeat``
  times: wall time, FE rollouts per mesh, NLP solves and the FE-verified final error.

The load average is recorded before and after (the machine is shared).  Writes
``benchmarks/results/replan_warm.json``.

    python benchmarks/replan_warm.py [--repeat 3] [--truth-friction 0.8]
"""

from __future__ import annotations

import argparse
import math
import os
import time
import tomllib
from pathlib import Path

import numpy as np

import fe_contact
from _common import write_results
from pushplan.config import load_scenario, parse_scenario
from pushplan.config.plan import parse_plan
from pushplan.identify import closed_loop as loop
from pushplan.planning import plan
from pushplan.planning.replan import replan

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
REFINEMENT_SCENARIOS = ("plan_steel_case3", "plan_rubber", "plan_yaw")


def _clock():
    return time.perf_counter(), time.process_time()


def _since(t):
    return time.perf_counter() - t[0], time.process_time() - t[1]


def _scenario(name: str, **edits):
    data = tomllib.loads((SCENARIOS / f"{name}.toml").read_text())
    for table, values in edits.items():
        data[table].update(values)
    return parse_scenario(data)


def measure_replans(truth_friction: float, refinement: str) -> dict:
    """The closed loop of plan_rubber with every warm re-plan timed against two cold ones."""
    model = load_scenario(SCENARIOS / "plan_rubber.toml")
    spec = parse_plan(model)
    truth = _scenario("plan_rubber", friction={"mu_x": model.mu_x * truth_friction, "mu_y": model.mu_y * truth_friction})
    coarse = _scenario("plan_rubber", block={"elements": list(spec.planning_elements),
                                             "quadrature": spec.planning_quadrature})
    rows = []

    def timed(scenario, shifted, obs, baseline=True, session=None):
        t = _clock()
        result = replan(scenario, shifted, obs, baseline=baseline, session=session)
        warm_wall, warm_cpu = _since(t)
        t = _clock()
        cold, _ = replan(scenario, shifted, obs, baseline=False)
        cold_wall, cold_cpu = _since(t)
        t = _clock()
        cold_coarse, _ = replan(coarse, shifted, obs, baseline=False)
        coarse_wall, coarse_cpu = _since(t)
        warm = result[0]
        rows.append({
            "push": len(rows) + 2, "remaining_steps": warm.spec.steps,
            "warm": {"wall_s": warm_wall, "cpu_s": warm_cpu, "status": warm.status, "fe_rollouts": warm.rollouts,
                     "nlp_iterations": [it.nlp_iterations for it in warm.iterations],
                     "calibrations": session.calibrations, "nlp_builds": session.nlp_builds},
            "cold": {"wall_s": cold_wall, "cpu_s": cold_cpu, "status": cold.status, "fe_rollouts": cold.rollouts},
            "cold_planning_mesh": {"wall_s": coarse_wall, "cpu_s": coarse_cpu, "status": cold_coarse.status,
                                   "fe_rollouts": cold_coarse.rollouts},
            "commands_difference_over_max_step": float(np.abs(warm.commands - cold_coarse.commands).max()
                                                       / spec.max_step),
            "final_pose_difference_m": float(np.hypot(*(warm.verified.lower[-1] - cold_coarse.verified.lower[-1])[:2])),
            "replan_tolerance_m": warm.spec.tolerance,
        })
        return result

    original = loop.PlanSession
    loop.replan = timed
    loop.PlanSession = lambda *a, **k: original(*a, **k, refinement=refinement)
    try:
        doc = loop.closed_loop(model, truth, spec).to_dict()
    finally:
        loop.replan, loop.PlanSession = replan, original
    med = {k: {q: float(np.median([r[k][q] for r in rows])) for q in ("wall_s", "cpu_s")}
           for k in ("warm", "cold", "cold_planning_mesh")}
    return {"truth_friction": truth_friction, "refinement": refinement, "pushes": rows, "median": med,
            "ratio_cold_over_warm": {q: med["cold"][q] / med["warm"][q] for q in ("wall_s", "cpu_s")},
            "ratio_cold_planning_mesh_over_warm": {q: med["cold_planning_mesh"][q] / med["warm"][q]
                                                   for q in ("wall_s", "cpu_s")},
            "closed_loop_final_error": doc["closed_loop"]["final_error"],
            "open_loop_final_error": doc["open_loop"]["final_error"], "tolerance": spec.tolerance}


def measure_loops(truth_friction: float, repeat: int) -> dict:
    """The whole closed loop of plan_rubber, warm (as ``closed-loop`` runs) and cold
    (``closed_loop(..., warm=False)``: every re-plan from the press on both meshes)."""
    model = load_scenario(SCENARIOS / "plan_rubber.toml")
    spec = parse_plan(model)
    truth = _scenario("plan_rubber", friction={"mu_x": model.mu_x * truth_friction, "mu_y": model.mu_y * truth_friction})
    runs = {"warm": [], "cold": []}
    for _ in range(repeat):
        for name in runs:
            t = _clock()
            doc = loop.closed_loop(model, truth, spec, warm=name == "warm").to_dict()
            wall, cpu = _since(t)
            runs[name].append({"wall_s": wall, "cpu_s": cpu, "final_error": doc["closed_loop"]["final_error"],
                               "push_wall_s": [it["wall_time_s"] for it in doc["iterations"]]})
    return {"runs": runs, "median": {k: {q: float(np.median([x[q] for x in v])) for q in ("wall_s", "cpu_s")}
                                     for k, v in runs.items()}}


def measure_refinements(repeat: int) -> dict:
    out = {}
    for name in REFINEMENT_SCENARIOS:
        scenario = load_scenario(SCENARIOS / f"{name}.toml")
        spec = parse_plan(scenario)
        runs = {"modifier": [], "exact_gradient": []}
        for _ in range(repeat):
            for method in runs:
                t = _clock()
                r = plan(scenario, spec, baseline=False, refinement=method)
                wall, cpu = _since(t)
                err = r.iterations[-1]
                best = min((it for it in r.iterations if it.phase == "verification"),
                           key=lambda it: it.position_error / spec.tolerance + math.radians(it.yaw_error_deg)
                           / spec.yaw_tolerance)
                runs[method].append({"wall_s": wall, "cpu_s": cpu, "status": r.status, "refinement": r.refinement,
                                     "fe_rollouts": r.rollouts, "nlp_solves": sum(it.resolved for it in r.iterations),
                                     "gauss_newton_steps": sum(it.gauss_newton for it in r.iterations),
                                     "final_position_error_m": best.position_error,
                                     "final_yaw_error_deg": best.yaw_error_deg if spec.yaw_targeted else None,
                                     "last_iteration_error_m": err.position_error})
        out[name] = {"tolerance": spec.tolerance, "runs": runs,
                     "median": {m: {q: float(np.median([x[q] for x in v])) for q in ("wall_s", "cpu_s")}
                                for m, v in runs.items()}}
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--truth-friction", type=float, default=0.8)
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    fe_contact.warm_up()
    replans = {m: measure_replans(args.truth_friction, m) for m in ("modifier", "exact_gradient")}
    loops = measure_loops(args.truth_friction, args.repeat)
    refinements = measure_refinements(args.repeat)
    result = {"load_average_before": load_before, "load_average_after": os.getloadavg(), "cpus": os.cpu_count(),
              "replan": replans, "closed_loop": loops, "refinement": refinements}
    for method, r in replans.items():
        print(f"closed loop plan_rubber (truth friction x{args.truth_friction}), warm refinement {method}: "
              f"final error {r['closed_loop_final_error']['position'] * 1e6:.3f} um (tolerance "
              f"{r['tolerance'] * 1e6:.3g} um), open loop {r['open_loop_final_error']['position'] * 1e6:.1f} um")
        for row in r["pushes"]:
            print(f"  before push {row['push']} ({row['remaining_steps']} left): warm {row['warm']['wall_s']:.3f} s "
                  f"({row['warm']['fe_rollouts']['planning']} rollouts), cold {row['cold']['wall_s']:.3f} s, "
                  f"cold on the planning mesh {row['cold_planning_mesh']['wall_s']:.3f} s; warm - cold commands "
                  f"{row['commands_difference_over_max_step']:.1e} max_step, final poses "
                  f"{row['final_pose_difference_m'] * 1e6:.3f} um apart")
        m = r["median"]
        print(f"  median re-plan: warm {m['warm']['wall_s']:.3f} s wall / {m['warm']['cpu_s']:.3f} s cpu, cold "
              f"{m['cold']['wall_s']:.3f} / {m['cold']['cpu_s']:.3f}, cold planning mesh "
              f"{m['cold_planning_mesh']['wall_s']:.3f} / {m['cold_planning_mesh']['cpu_s']:.3f}; cold / warm "
              f"{r['ratio_cold_over_warm']['wall_s']:.1f}x wall, {r['ratio_cold_over_warm']['cpu_s']:.1f}x cpu")
    for name, runs in loops["runs"].items():
        m = loops["median"][name]
        print(f"closed loop {name}: {m['wall_s']:.2f} s wall, {m['cpu_s']:.2f} s cpu (median of {len(runs)}), final "
              f"error {runs[-1]['final_error']['position'] * 1e6:.3f} um")
    for name, row in refinements.items():
        for method, runs in row["runs"].items():
            x = runs[-1]
            yaw = "" if x["final_yaw_error_deg"] is None else f", yaw {x['final_yaw_error_deg']:.5f} deg"
            print(f"{name:>18} {method:>15}: {row['median'][method]['wall_s']:.2f} s wall "
                  f"{row['median'][method]['cpu_s']:.2f} s cpu (median of {len(runs)}), rollouts "
                  f"{x['fe_rollouts']['planning']} + {x['fe_rollouts']['verification']}, NLP solves {x['nlp_solves']}, "
                  f"Gauss-Newton {x['gauss_newton_steps']}, final error {x['final_position_error_m'] * 1e6:.4f} um{yaw}")
    print(f"load average {load_before[0]:.1f} -> {result['load_average_after'][0]:.1f} on {os.cpu_count()} cpus")
    print(f"wrote {write_results('replan_warm', result)}")


if __name__ == "__main__":
    main()
