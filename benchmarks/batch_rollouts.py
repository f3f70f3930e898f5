"""Throughput of batch rollouts on warm workers (issue 40 item 1), every figure in one run:

n = 32 command sequences of T = 6 pushes (random around the ``plan_rubber`` target, the
draws of a sampling MPC) from the pressed block, on the planning mesh of ``plan_rubber``
(6 x 6 x 2, quadrature 2) and, with ``--verification``, on its verification mesh
(12 x 12 x 4, quadrature 3; about 20 minutes):

- ``single``: 32 ``PushModel.rollout`` calls one after the other in this process;
- ``pool_P``: ``PushModel.batch_rollouts`` on P = 1, 2 and all CPUs, timed warm (the
  pool already started and holding the start state: what every call after the first
  costs) and the first call cold (the workers' start included);
- the CPU time (user + system, this process and the workers) per rollout: on a busy
  machine the wall-time ratio measures the other users' load as much as the pool, the CPU
  time per rollout (pool against single) measures what the pool adds;
- the same for the Jacobian form (``rollout_with_jacobian`` / ``batch_rollouts_with_jacobian``).

Throughput = rollouts / wall time of the process, in total and per core (total / P).
The load average before and after is recorded: the machine is shared.

    python benchmarks/batch_rollouts.py [--quick] [--verification]

Writes ``benchmarks/results/batch_rollouts.json``.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from _common import write_results
from pushplan.config.plan import press_commands
from pushplan.config.scenario import load_scenario
from pushplan.planning.batch import default_processes
from pushplan.planning.push_model import PushModel
from pushplan.resources import scenario_path

N, T = 32, 6
REPEATS = 3
MESHES = {"planning 6x6x2 q2": ((6, 6, 2), 2), "verification 12x12x4 q3": ((12, 12, 4), 3)}


def controls(seed: int = 0) -> np.ndarray:
    """(N, T, 3) pushes of about 0.55 mm toward (3.0, 1.5) mm with noise, m and rad."""
    rng = np.random.default_rng(seed)
    mean = np.array([5e-4, 2.5e-4, 0.0])
    return mean + rng.normal(0.0, [2e-4, 2e-4, 0.01], (N, T, 3))


def cpu_seconds(pids) -> float:
    """User + system CPU time of this process and of the worker processes ``pids``, s."""
    tick = os.sysconf("SC_CLK_TCK")
    total = time.process_time()
    for pid in pids:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


def timed(f, repeats: int, pids=()) -> tuple[list[float], list[float]]:
    """Wall and CPU times (s) of ``repeats`` calls of ``f``."""
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = cpu_seconds(pids), time.perf_counter()
        f()
        wall.append(time.perf_counter() - t0)
        cpu.append(cpu_seconds(pids) - c0)
    return wall, cpu


def rates(times: tuple[list[float], list[float]], cores: int) -> dict:
    wall, cpu = times
    best = min(wall)
    return {"wall_s": wall, "rollouts_per_s": N / best, "per_core": N / best / cores,
            "median_rollouts_per_s": N / float(np.median(wall)),
            "cpu_s_per_rollout": float(np.median(cpu)) / N}


def measure(push: PushModel, kind: str, repeats: int) -> dict:
    u = controls()
    single = push.rollout if kind == "poses" else push.rollout_with_jacobian
    batch = push.batch_rollouts if kind == "poses" else push.batch_rollouts_with_jacobian
    out = {"single": rates(timed(lambda: [single(c) for c in u], repeats), 1)}
    for p in sorted({1, 2, default_processes()}):
        push.close()
        t0 = time.perf_counter()
        batch(u, processes=p)
        cold = time.perf_counter() - t0
        pids = [w.process.pid for w in push.pool(p)._workers]
        out[f"pool_{p}"] = {**rates(timed(lambda p=p: batch(u, processes=p), repeats, pids), p),
                            "cold_first_call_s": cold}
        out[f"pool_{p}"]["speedup_vs_single"] = out[f"pool_{p}"]["rollouts_per_s"] / out["single"]["rollouts_per_s"]
        out[f"pool_{p}"]["median_speedup_vs_single"] = (out[f"pool_{p}"]["median_rollouts_per_s"]
                                                        / out["single"]["median_rollouts_per_s"])
    push.close()
    return out


def main() -> None:
    quick = "--quick" in sys.argv
    scenario = load_scenario(scenario_path("plan_rubber.toml"))
    results = {"n": N, "T": T, "load_before": os.getloadavg()}
    for label, (elements, quadrature) in MESHES.items():
        if label.startswith("verification") and "--verification" not in sys.argv:
            continue
        push = PushModel(scenario.model(elements, quadrature), press_commands(scenario))
        push.pressed  # noqa: B018 (the press, once, outside the timings)
        results[label] = {kind: measure(push, kind, 1 if quick else REPEATS) for kind in ("poses", "jacobian")}
        for kind, r in results[label].items():
            for name, v in r.items():
                extra = f"  x{v['speedup_vs_single']:.2f} (median x{v['median_speedup_vs_single']:.2f})" \
                    if "speedup_vs_single" in v else ""
                print(f"{label:24s} {kind:8s} {name:7s} {v['rollouts_per_s']:7.2f} rollouts/s "
                      f"({v['per_core']:6.2f} per core, {v['cpu_s_per_rollout'] * 1e3:6.1f} ms CPU each){extra}")
    results["load_after"] = os.getloadavg()
    print("load average before / after:", results["load_before"], results["load_after"])
    print("wrote", write_results("batch_rollouts", results))


if __name__ == "__main__":
    main()
