"""Throughput of batch rollouts on warm workers (issue 40 item 1), every figure in one run:

n = 32 command sequences of T = 6 pushes (random around the ``plan_rubber`` target, the
draws of a sampling MPC) from the pressed block, on the planning mesh of ``plan_rubber``
(6 x 6 x 2, quadrature 2) and, with ``--verification``, on its verification mesh
(12 x 12 x 4, quadrature 3; about 20 minutes):

- ``single``: 32 ``PushModel.rollout`` calls one after the other in this process;
- ``pool_P``: ``PushModel.batch_rollouts`` on P = 1, 2 and all CPUs (one ``PushModel``
  and its warm pool per P, all started before the timings; the first call of each, the
  workers' start included, is timed apart as ``cold_first_call_s``);
- the rounds are interleaved (single, pool_1, pool_2, ... then again), so that a change
  of the machine's load falls on all of them alike; each round's speedup is
  ``single wall / pool wall`` of that round, reported as the median and the best round;
- the CPU time (user + system, this process and the workers) per rollout: what the
  pool adds to a rollout's own cost (messages, pickling), whatever the load;
- ``cpu_bound_speedup``: the single calls' CPU time over the busiest worker's (plus
  this process's) in the batch: the speed-up if each worker had a core to itself, the
  pool's load balance and its own CPU cost included (the cores' shared cache and
  memory not).  Not a measurement of wall time: on a machine shared with other
  sessions, Linux's autogroup scheduling (``sched_autogroup_enabled`` = 1, recorded)
  gives this session's processes one share together, and the pool's workers then split
  it rather than add to it (measured here at load 8-11: x0.95-1.04 in wall time);
- the threads of this process that ran during the single calls (their CPU time grew):
  a single call on more than one thread would make the comparison one of cores against
  threads; the BLAS thread counts (threadpoolctl) are recorded too;
- the same for the Jacobian form (``rollout_with_jacobian`` / ``batch_rollouts_with_jacobian``).

Throughput = rollouts / wall time of the process, in total and per core (total / P).
The load average before, during (per round) and after is recorded: the machine may
be shared, and the wall-time ratio then measures the other users' load as well.
Nothing is read from the environment (fe_contact limits BLAS to one thread on import;
the workers run their dense kernels on one thread).  About 2 minutes on an idle
2-core machine (``--quick``: one round, 30 s).

    python benchmarks/batch_rollouts.py [--quick] [--verification]

Writes ``benchmarks/results/batch_rollouts.json``.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
from threadpoolctl import threadpool_info

from _common import write_results
from pushplan.config.plan import press_commands
from pushplan.config.scenario import load_scenario
from pushplan.planning.batch import default_processes
from pushplan.planning.push_model import PushModel
from pushplan.resources import scenario_path

N, T = 32, 6
ROUNDS = 3
MESHES = {"planning 6x6x2 q2": ((6, 6, 2), 2), "verification 12x12x4 q3": ((12, 12, 4), 3)}


def controls(seed: int = 0) -> np.ndarray:
    """(N, T, 3) pushes of about 0.55 mm toward (3.0, 1.5) mm with noise, m and rad."""
    rng = np.random.default_rng(seed)
    mean = np.array([5e-4, 2.5e-4, 0.0])
    return mean + rng.normal(0.0, [2e-4, 2e-4, 0.01], (N, T, 3))


def _stat_cpu(path: str) -> float:
    """User + system CPU time (s) of ``/proc/<pid>/stat`` or ``/proc/self/task/<tid>/stat``."""
    with open(path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_seconds(pids) -> float:
    """User + system CPU time of this process and of the worker processes ``pids``, s."""
    return time.process_time() + sum(_stat_cpu(f"/proc/{pid}/stat") for pid in pids)


def thread_times() -> dict:
    """CPU time (s) of each thread of this process."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            out[tid] = _stat_cpu(f"/proc/self/task/{tid}/stat")
        except OSError:
            pass
    return out


def timed(f, pids=()) -> tuple[float, float, float]:
    """Wall and CPU time (s) of one call of ``f``, and the CPU time of its busiest
    process (this one, or the busiest worker of ``pids`` plus this one's)."""
    each = [_stat_cpu(f"/proc/{pid}/stat") for pid in pids]
    c0, t0 = cpu_seconds(pids), time.perf_counter()
    own = time.process_time()
    f()
    wall, cpu = time.perf_counter() - t0, cpu_seconds(pids) - c0
    own = time.process_time() - own
    busiest = max((_stat_cpu(f"/proc/{pid}/stat") - e for pid, e in zip(pids, each, strict=True)), default=0.0)
    return wall, cpu, busiest + own


def summary(wall: list[float], cpu: list[float], cores: int) -> dict:
    best = min(wall)
    return {"wall_s": wall, "rollouts_per_s": N / best, "per_core": N / best / cores,
            "median_rollouts_per_s": N / float(np.median(wall)), "cpu_s_per_rollout": float(np.median(cpu)) / N}


def measure(model, press, kind: str, rounds: int) -> dict:
    """Interleaved rounds of 32 single calls and of one batch on each pool (module docstring)."""
    u = controls()
    cores = sorted({1, 2, default_processes()})
    pushes = {p: PushModel(model, press) for p in [0, *cores]}  # 0: the single calls
    single = pushes[0].rollout if kind == "poses" else pushes[0].rollout_with_jacobian
    batches = {p: (pushes[p].batch_rollouts if kind == "poses" else pushes[p].batch_rollouts_with_jacobian)
               for p in cores}
    cold = {}
    for p in cores:
        t0 = time.perf_counter()
        batches[p](u, processes=p)
        cold[p] = time.perf_counter() - t0
    pushes[0].pressed  # noqa: B018 (the press, outside the timings)
    wall = {p: [] for p in [0, *cores]}
    cpu = {p: [] for p in [0, *cores]}
    busiest = {p: [] for p in [0, *cores]}
    loads, threads_used = [], 0
    try:
        for _ in range(rounds):
            loads.append(os.getloadavg()[0])
            before = thread_times()
            times = timed(lambda: [single(x) for x in u])
            after = thread_times()
            threads_used = max(threads_used, sum(after[t] - before.get(t, 0.0) > 0.02 for t in after))
            for p in [0, *cores]:
                if p:
                    pids = [wk.process.pid for wk in pushes[p].pool(p)._workers]
                    times = timed(lambda p=p: batches[p](u, processes=p), pids)
                wall[p].append(times[0])
                cpu[p].append(times[1])
                busiest[p].append(times[2])
    finally:
        for push in pushes.values():
            push.close()
    out = {"single": {**summary(wall[0], cpu[0], 1), "threads_used": threads_used}, "load_per_round": loads}
    for p in cores:
        ratios = [s / b for s, b in zip(wall[0], wall[p], strict=True)]
        out[f"pool_{p}"] = {**summary(wall[p], cpu[p], p), "cold_first_call_s": cold[p],
                            "speedup_vs_single": float(np.median(ratios)), "best_round_speedup": max(ratios),
                            "round_speedups": ratios,
                            "cpu_ratio_vs_single": float(np.median(cpu[p]) / np.median(cpu[0])),
                            "cpu_bound_speedup": float(np.median(cpu[0]) / np.median(busiest[p]))}
    out["all_cores"] = default_processes()
    return out


def report(label: str, kind: str, r: dict) -> None:
    for name, v in r.items():
        if not isinstance(v, dict):
            continue
        extra = (f"  x{v['speedup_vs_single']:.2f} median of rounds (best x{v['best_round_speedup']:.2f}), "
                 f"CPU x{v['cpu_ratio_vs_single']:.3f}, CPU-bound x{v['cpu_bound_speedup']:.2f}") \
            if "speedup_vs_single" in v else \
            f"  on {v['threads_used']} thread(s)"
        print(f"{label:24s} {kind:8s} {name:7s} {v['median_rollouts_per_s']:7.2f} rollouts/s "
              f"({v['median_rollouts_per_s'] / (1 if name == 'single' else int(name[5:])):6.2f} per core, "
              f"{v['cpu_s_per_rollout'] * 1e3:6.1f} ms CPU each){extra}")
    print(f"{'':24s} {kind:8s} load average per round: {', '.join(f'{x:.2f}' for x in r['load_per_round'])}")


def _autogroup() -> str:
    """``/proc/sys/kernel/sched_autogroup_enabled``: with 1, Linux shares the CPUs between
    sessions first, so under other sessions' load the workers share this session's part."""
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled") as f:
            return f.read().strip()
    except OSError:
        return "unknown"


def main() -> None:
    quick = "--quick" in sys.argv
    t0 = time.perf_counter()
    scenario = load_scenario(scenario_path("plan_rubber.toml"))
    results = {"n": N, "T": T, "load_before": os.getloadavg(), "cpus": default_processes(),
               "sched_autogroup": _autogroup(),
               "blas": [{k: i[k] for k in ("internal_api", "num_threads", "filepath")} for i in threadpool_info()]}
    for label, (elements, quadrature) in MESHES.items():
        if label.startswith("verification") and "--verification" not in sys.argv:
            continue
        model, press = scenario.model(elements, quadrature), press_commands(scenario)
        results[label] = {kind: measure(model, press, kind, 1 if quick else ROUNDS) for kind in ("poses", "jacobian")}
        for kind, r in results[label].items():
            report(label, kind, r)
    results["load_after"] = os.getloadavg()
    results["wall_s"] = time.perf_counter() - t0
    print(f"load average before / after: {results['load_before'][0]:.2f} / {results['load_after'][0]:.2f} "
          f"on {results['cpus']} CPUs; BLAS threads "
          f"{', '.join(str(b['num_threads']) for b in results['blas'])}; {results['wall_s']:.0f} s")
    print("wrote", write_results("batch_rollouts", results))


if __name__ == "__main__":
    main()
