"""Sampling MPC (CEM on the FE model, issue 40 item 2) against ``pushplan plan`` on the
same target and the same FE model, in one run:

``plan_rubber``'s target (3.0, 1.5) mm in 6 pushes of at most 0.8 mm, tolerance 5 um,
with the block meshed at the planning resolution (6 x 6 x 2, quadrature 2) so that the
planner's verification mesh and the CEM's model are the same FE model:

- ``plan``: :func:`pushplan.planning.plan` (reduced model + NLP + FE correction loop);
- ``cem``: :func:`pushplan.planning.sampling.cem_mpc` with 16 samples per iteration on
  the warm workers (all CPUs), at most 30 iterations per executed command.

Final error (m), FE rollouts, wall time (s).  The machine is shared: load averages recorded.

    python benchmarks/sampling_mpc.py

Writes ``benchmarks/results/sampling_mpc.json``.
"""

from __future__ import annotations

import os
import time

import numpy as np

from _common import write_results
from pushplan.config.files import read_toml
from pushplan.config.plan import parse_plan, press_commands
from pushplan.config.scenario import parse_scenario
from pushplan.planning import plan
from pushplan.planning.push_model import PushModel
from pushplan.planning.sampling import FeRolloutBackend, cem_mpc
from pushplan.resources import scenario_path

SAMPLES = 16


def main() -> None:
    table = read_toml(scenario_path("plan_rubber.toml"))
    table["block"].update(elements=[6, 6, 2], quadrature=2)
    scenario = parse_scenario(table, name="plan_rubber_planning_mesh")
    spec = parse_plan(scenario)
    target = np.array(spec.target[:2])  # from the rest pose after the press
    out = {"target_m": target.tolist(), "steps": spec.steps, "max_step_m": spec.max_step, "tolerance_m": spec.tolerance,
           "load_before": os.getloadavg()}
    t0 = time.perf_counter()
    result = plan(scenario, spec, baseline=False)
    final = result.verified.final()
    out["plan"] = {"error_m": float(np.hypot(*(final[:2] - target))), "status": result.status,
                   "rollouts": result.rollouts, "wall_s": time.perf_counter() - t0}
    with PushModel(scenario.model(), press_commands(scenario)) as push:
        t0 = time.perf_counter()
        backend = FeRolloutBackend(push, SAMPLES)
        origin = backend.pose[:2].copy()
        cem = cem_mpc(backend, origin + target, spec.steps, spec.max_step, spec.tolerance)
        out["cem"] = {"error_m": cem.error, "reached": cem.reached, "rollouts": cem.rollouts,
                      "iterations": cem.iterations, "wall_s": time.perf_counter() - t0,
                      "processes": backend.push.pool().processes}
    out["load_after"] = os.getloadavg()
    for name in ("plan", "cem"):
        r = out[name]
        print(f"{name:5s} error {r['error_m'] * 1e6:8.3f} um  rollouts {r['rollouts']}  wall {r['wall_s']:7.1f} s")
    print("load average before / after:", out["load_before"], out["load_after"])
    print("wrote", write_results("sampling_mpc", out))


if __name__ == "__main__":
    main()
