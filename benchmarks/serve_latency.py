"""Latency of ``pushplan serve`` measured from a client process (issue 41), and isolation of
sessions under load.

The server runs as its own process (``pushplan serve --address 127.0.0.1:0``); this process
is the client.  On ``plan_rubber`` (planning mesh 6 x 6 x 2, session without the
verification mesh, as ``closed-loop`` re-plans): ``Open`` (``--opens`` calls), ``Plan``,
a warm ``Replan`` after one executed push and a ``Rollout`` of 3 pushes (``--calls`` each):
median and p99 of the client's wall time.  The rollout is compared with the same rollout
in this process (``FeRollouts`` on the same mesh, same start state).  The server's CPU
(its process tree, user + system) over ``--idle`` s with an open session and no call.
Then ``--clients`` client processes, each its own session, each ``--replans`` re-plans
with its own observations at once; every answer is compared with the same sequence run
by one client alone.

Writes benchmarks/results/serve_latency.json (every figure, the load average before and
after).  ``--quick`` for a smoke run.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "pushplan" / "scenarios" / "plan_rubber.toml"
COMMANDS = [[0.5e-3, 0.25e-3, 0.0]] * 3


def _stats(times) -> dict:
    t = np.asarray(times)
    return {"calls": len(t), "median_s": float(np.median(t)), "p99_s": float(np.percentile(t, 99)),
            "max_s": float(t.max()), "min_s": float(t.min())}


def _timed(fn, n: int) -> tuple[list[float], object]:
    times, out = [], None
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def _tree_cpu(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its descendants (from /proc)."""
    parent, cpu = {}, {}
    tick = os.sysconf("SC_CLK_TCK")
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parent[int(d.name)] = int(fields[1])
        cpu[int(d.name)] = (int(fields[11]) + int(fields[12])) / tick
    tree, grew = {pid}, True
    while grew:
        new = {p for p, pp in parent.items() if pp in tree} - tree
        tree |= new
        grew = bool(new)
    return sum(cpu.get(p, 0.0) for p in tree)


def _observation(first: dict, i: int) -> list[float]:
    """Client ``i``'s observed pose after the first push: the plan's own pose there, off by
    ``i`` um in x and y (as a truth on other friction would be)."""
    x, y, yaw = first["poses"][1]
    return [x + 1e-6 * i, y - 1e-6 * i, yaw]


def _client_run(address: str, i: int, replans: int) -> list:
    """One client's session: plan, then ``replans`` re-plans after the first push with
    observation ``i``; returns every answer's commands."""
    from pushplan.client import Client

    with Client(address, timeout=600.0) as c:
        s = c.open(scenario_path=str(SCENARIO), verify=False)
        first = s.plan()
        answers = [first["commands"]]
        for _ in range(replans):
            answers.append(s.replan([first["commands"][0]], _observation(first, i))["commands"])
        s.close()
    return answers


def _in_process(n: int) -> tuple[list[float], list[float]]:
    """The same warm re-plans and rollouts in this process (a PlanSession of the planning
    mesh, as the server's): their wall times."""
    from pushplan.config import load_scenario
    from pushplan.config.commands import planar_commands
    from pushplan.config.plan import parse_plan
    from pushplan.planning.planner import PlanSession
    from pushplan.planning.replan import Start, remaining_spec

    sc = load_scenario(SCENARIO)
    spec = parse_plan(sc)
    session = PlanSession(sc, spec, verify=False)
    first = session.plan(spec, baseline=False)
    executed = planar_commands(first.commands[:1])
    start = Start(executed, np.array(_observation({"poses": first.verified.lower.tolist()}, 0)))
    session.continue_from(executed)
    replans = _timed(lambda: session.plan(remaining_spec(spec, start), baseline=False), n)[0]
    rollouts = _timed(lambda: session.coarse.rollout(np.array(COMMANDS), release=False), n)[0]
    return replans, rollouts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--opens", type=int, default=10)
    ap.add_argument("--idle", type=float, default=5.0)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--replans", type=int, default=50)
    ap.add_argument("--quick", action="store_true", help="20 calls, 2 opens, 2 clients x 3 re-plans")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "serve_latency.json"))
    args = ap.parse_args(argv)
    if args.quick:
        args.calls, args.opens, args.idle, args.clients, args.replans = 20, 2, 1.0, 2, 3
    from pushplan.client import Client

    load_before = os.getloadavg()
    server = subprocess.Popen([sys.executable, "-m", "pushplan.cli", "serve", "--address", "127.0.0.1:0",
                               "--root", str(SCENARIO.parent), "--max-sessions", str(max(args.clients, 2))],
                              stdout=subprocess.PIPE, text=True)
    try:
        address = server.stdout.readline().split("listening on ")[1].strip()
        doc = {"scenario": SCENARIO.name, "server": "pushplan serve, its own process; the client this process",
               "cores": os.cpu_count()}
        with Client(address, timeout=600.0) as c:
            opens = []
            for _ in range(args.opens):
                t0 = time.perf_counter()
                s = c.open(scenario_path=str(SCENARIO), verify=False)
                opens.append(time.perf_counter() - t0)
                s.close()
            s = c.open(scenario_path=str(SCENARIO), verify=False)
            plans, first = _timed(s.plan, args.calls)
            replans, _ = _timed(lambda: s.replan([first["commands"][0]], _observation(first, 0)), args.calls)
            rollouts, _ = _timed(lambda: s.rollout(COMMANDS), args.calls)
            cpu0, t0 = _tree_cpu(server.pid), time.perf_counter()
            time.sleep(args.idle)
            idle_cpu = (_tree_cpu(server.pid) - cpu0) / (time.perf_counter() - t0)
            s.close()
        local_replans, local = _in_process(args.calls)
        doc |= {"open": _stats(opens), "plan": _stats(plans), "warm_replan": _stats(replans),
                "warm_replan_in_process": _stats(local_replans),
                "replan_ratio_median": float(np.median(replans) / np.median(local_replans)),
                "rollout_3_pushes_6x6x2": _stats(rollouts), "rollout_in_process": _stats(local),
                "rollout_ratio_median": float(np.median(rollouts) / np.median(local)),
                "server_idle_cpu_s_per_s": idle_cpu}
        singles = [_client_run(address, i, args.replans) for i in range(args.clients)]
        t0 = time.perf_counter()
        with multiprocessing.get_context("spawn").Pool(args.clients) as pool:
            together = pool.starmap(_client_run, [(address, i, args.replans) for i in range(args.clients)])
        wall = time.perf_counter() - t0
        diff = max(float(np.max(np.abs(np.array(a) - np.array(b)))) for x, y in zip(singles, together, strict=True)
                   for a, b in zip(x, y, strict=True))
        distinct = len({json.dumps(x[-1]) for x in together})
        doc["isolation"] = {"clients": args.clients, "replans_each": args.replans, "wall_s": wall,
                            "max_abs_difference_from_single_client_m": diff,
                            "distinct_final_answers": distinct, "all_equal": diff == 0.0}
    finally:
        server.terminate()
        doc["server_exit"] = server.wait(60)
    doc["load_average_before"], doc["load_average_after"] = load_before, os.getloadavg()
    print(json.dumps(doc, indent=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
