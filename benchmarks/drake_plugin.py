"""The Drake plugin's costs (issue 40 item 3), in one run:

- ``program``: ``plan_rubber``'s target (3.0, 1.5) mm in 6 pushes of at most 0.8 mm,
  tolerance 5 um, the block meshed at the planning resolution (6 x 6 x 2, quadrature 2)
  as in ``benchmarks/sampling_mpc.py``: :func:`pushplan.drake.plan_to_target` (a
  ``MathematicalProgram``, the FE rollout as a constraint with its exact gradient,
  SNOPT) against :func:`pushplan.planning.plan`: final error, FE rollouts, wall time,
  and the distance between the two final poses;
- ``system``: the same 6 pushes (the plan's commands) as absolute gripper poses through
  :class:`pushplan.drake.FePushSystem` in :func:`pushplan.drake.arm_diagram` (one FE
  step per 10 ms period, simulated 5 ms into each), against the 6 FE steps alone
  (:meth:`PushModel.step_report`), then 5 idle periods (no FE step: the arm's integration);
- ``import``: ``import pydrake.all`` in a fresh process.

Wall times, s; the machine is shared: load averages recorded.

    python benchmarks/drake_plugin.py

Writes ``benchmarks/results/drake_plugin.json``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
from pydrake.systems.analysis import Simulator

from _common import write_results
from pushplan.config.files import read_toml
from pushplan.config.plan import parse_plan
from pushplan.config.scenario import parse_scenario
from pushplan.drake import arm_diagram, plan_to_target
from pushplan.planning import plan
from pushplan.planning.push_model import PushModel
from pushplan.resources import scenario_path

PERIOD = 0.01  # s


def _program(scenario, spec, push) -> dict:
    t0 = time.perf_counter()
    result = plan(scenario, spec, baseline=False)
    final = result.verified.final()
    out = {"plan": {"error_m": float(np.hypot(*(final[:2] - spec.target[:2]))), "status": result.status,
                    "rollouts": result.rollouts, "wall_s": time.perf_counter() - t0}}
    ours = plan_to_target(scenario, spec, push)
    out["drake"] = {"error_m": ours.error, "reached": ours.reached, "solver": ours.solver, "success": ours.success,
                    "rollouts": ours.rollouts, "wall_s": ours.wall_time}
    out["final_poses_apart_m"] = float(np.hypot(*(ours.final[:2] - final[:2])))
    return out, result.commands


def _system(push, commands) -> dict:
    t0, state = time.perf_counter(), push.pressed.state
    for c in commands:
        state, _ = push.step_report(state, c)
    alone = time.perf_counter() - t0
    diagram, _, fe = arm_diagram(push, PERIOD)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    t0 = time.perf_counter()
    for k, gripper in enumerate(np.cumsum(commands, axis=0)):
        diagram.get_input_port(0).FixValue(context, gripper)
        simulator.AdvanceTo(PERIOD * (k + 0.5))
    moving = time.perf_counter() - t0
    steps = fe.held(fe.GetMyContextFromRoot(context)).steps
    t0 = time.perf_counter()
    simulator.AdvanceTo(PERIOD * (len(commands) + 5.5))
    idle = time.perf_counter() - t0
    return {"fe_steps_alone_s": alone, "periods": len(commands), "fe_steps_in_diagram": steps,
            "diagram_moving_s": moving, "idle_periods": 5, "diagram_idle_s": idle}


def main() -> None:
    table = read_toml(scenario_path("plan_rubber.toml"))
    table["block"].update(elements=[6, 6, 2], quadrature=2)
    scenario = parse_scenario(table, name="plan_rubber_planning_mesh")
    spec = parse_plan(scenario)
    out = {"target_m": list(spec.target[:2]), "steps": spec.steps, "tolerance_m": spec.tolerance,
           "load_before": os.getloadavg()}
    push = PushModel.from_scenario(scenario)
    out["program"], commands = _program(scenario, spec, push)
    out["system"] = _system(push, commands)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import pydrake.all"], check=True)
    out["import_pydrake_all_s"] = time.perf_counter() - t0
    out["load_after"] = os.getloadavg()
    p = out["program"]
    for name in ("plan", "drake"):
        r = p[name]
        print(f"{name:5s} error {r['error_m'] * 1e6:8.3f} um  rollouts {r['rollouts']}  wall {r['wall_s']:6.1f} s")
    print(f"final poses {p['final_poses_apart_m'] * 1e6:.3f} um apart")
    s = out["system"]
    print(f"6 FE steps alone {s['fe_steps_alone_s']:.2f} s; in the diagram {s['diagram_moving_s']:.2f} s "
          f"({s['fe_steps_in_diagram']} steps); 5 idle periods {s['diagram_idle_s']:.2f} s")
    print(f"import pydrake.all (process) {out['import_pydrake_all_s']:.2f} s")
    print("load average before / after:", out["load_before"], out["load_after"])
    print("wrote", write_results("drake_plugin", out))


if __name__ == "__main__":
    main()
