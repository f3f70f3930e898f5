"""Latency of ``pushplan serve`` from a client process against the same work in that
process, at the same load, in one run (issue 41).

The server runs as its own process (``pushplan serve --address 127.0.0.1:0``); this process
is the client.  The case is ``plan_rubber`` on its planning mesh (6 x 6 x 2, sessions
without the verification mesh but those of the verified re-plan):

- **the closed loop**, ``--loops`` times at most (no new loop after ``--loop-budget`` s): ``Open``, ``Plan``, then the loop's 5 warm
  re-plans (``Replan``, ``closed_loop=True``, as ``pushplan closed-loop`` re-plans) on the
  observations of a truth with 0.8 times the model's friction on the verification mesh
  12 x 12 x 4 (the truth of ``benchmarks/replan_warm.py``, the issue's 35 ms; run once before
  the timing: the answers are deterministic, and every loop's are checked equal).  Unlike
  ``closed-loop``, whose first plan is verified on both meshes, the sessions plan on the
  planning mesh alone, so the re-plans follow that first plan.
  Each loop through the service is followed by the same loop in this process
  (:class:`pushplan.service.worker.SessionState`, the session's own code without the wire),
  so both see the same load: per call, overhead = service time - in-process time;
- **the verified re-plan**, ``--verified-loops`` times at most (no new loop after
  ``--verified-budget`` s): the default ``Replan`` (no ``closed_loop``) in a session opened with
  ``verify`` true (the default), on the same requests: each re-plan is corrected on the
  planning mesh and then verified on the verification mesh (12 x 12 x 4, quadrature 3), so it
  costs that mesh's FE rollouts too; through the service only (each answer's ``session_s`` /
  ``session_cpu_s`` is the session's part), by pushes left;
- **rollouts** of 3 pushes from the press, ``--calls`` times at most (none started after
  ``--rollout-budget`` s), alternating service and in-process;
- a session's ``Info`` round trip, ``--calls`` times: the wire with no work behind it;
- the server's CPU (its process tree, user + system) over ``--idle`` s with an open session
  and no call (idle = 0);
- **isolation**: ``--clients`` client processes at once, each its own session, a plan and
  ``--replans`` re-plans of the last push with its own observation; every answer equal to the
  same sequence run by one client alone.

Each service answer carries ``server_s`` (the server's handler) and ``session_s`` /
``session_cpu_s`` (the session's process): the wire, client time - ``session_s`` of the same
call, splits into client <-> server (gRPC, JSON) and server <-> session (the pipe).  Under
load the paired difference service - in process is noisy (each call waits for a core its own
way); the wire is measured within one call.  Medians and p99 in s; the load average before and after.  Writes
benchmarks/results/serve_latency.json.  ``--quick`` for a smoke run.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "pushplan" / "scenarios" / "plan_rubber.toml"
COMMANDS = [[0.5e-3, 0.25e-3, 0.0]] * 3
TRUTH_FRICTION = 0.8


def _stats(times) -> dict:
    t = np.asarray(times, float)
    return {"calls": len(t), "median_s": float(np.median(t)), "p99_s": float(np.percentile(t, 99)),
            "max_s": float(t.max()), "min_s": float(t.min())}


def _tree_cpu(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its descendants, the ended ones they waited
    for included (from /proc)."""
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
        cpu[int(d.name)] = sum(int(f) for f in fields[11:15]) / tick
    tree, grew = {pid}, True
    while grew:
        new = {p for p, pp in parent.items() if pp in tree} - tree
        tree |= new
        grew = bool(new)
    return sum(cpu.get(p, 0.0) for p in tree)


def _truth_pose(model, state, command) -> tuple:
    """One push on the truth: (state after it, lower-face pose (x, y, yaw) from rest)."""
    from fe_contact import Command
    from pushplan.run import drive

    run = drive(model, [Command(command[0], command[1], 0.0, command[2])], state)
    s = run.summary.steps[-1]
    return run.state, [s.lower_centroid[0], s.lower_centroid[1], s.lower_yaw]


def closed_loop_requests(text: str, warm_steps: bool | None = None) -> tuple[list[dict], list]:
    """The closed loop once in this process: the ``Replan`` requests (executed pushes and the
    truth's observed pose after them) and every answer's commands; ``warm_steps`` sets the
    session planning mesh's :attr:`FeRollouts.warm_steps` (default: as a session sets it)."""
    from pushplan.config import parse_scenario
    from pushplan.config.plan import press_commands
    from pushplan.run import drive
    from pushplan.service.worker import SessionState

    data = tomllib.loads(text)
    data["friction"] = {**data["friction"], "mu_x": data["friction"]["mu_x"] * TRUTH_FRICTION,
                        "mu_y": data["friction"]["mu_y"] * TRUTH_FRICTION}
    truth_sc = parse_scenario(data, name="truth")
    truth = truth_sc.model()
    state = drive(truth, press_commands(truth_sc)).state
    session = SessionState(text, SCENARIO.stem, verify=False)
    if warm_steps is not None:
        session.session.coarse.warm_steps = warm_steps
    answer = session.plan({})
    requests, answers, executed = [], [answer["commands"]], []
    for _ in range(session.spec.steps - 1):
        executed.append(answer["commands"][0])
        state, observed = _truth_pose(truth, state, executed[-1])
        requests.append({"executed": list(executed), "observed": observed, "closed_loop": True})
        answer = session.replan(requests[-1])
        answers.append(answer["commands"])
    return requests, answers


def _service_loop(client, requests: list[dict]) -> dict:
    """One closed loop through the service: wall times, the answers' timing fields, commands."""
    t0 = time.perf_counter()
    s = client.open(scenario_path=str(SCENARIO), verify=False)
    out = {"open": time.perf_counter() - t0, "replan": [], "parts": [], "commands": []}
    t0 = time.perf_counter()
    answer = s.plan()
    out["plan"] = time.perf_counter() - t0
    out["commands"].append(answer["commands"])
    for r in requests:
        t0 = time.perf_counter()
        answer = s.replan(r["executed"], r["observed"], closed_loop=True)
        out["replan"].append(time.perf_counter() - t0)
        out["parts"].append((answer["server_s"], answer["session_s"], answer["session_cpu_s"], answer["wall_time_s"]))
        out["commands"].append(answer["commands"])
    s.close()
    return out


def _local_loop(text: str, requests: list[dict]) -> dict:
    """The same loop in this process: the session's code, no wire."""
    from pushplan.service.worker import SessionState

    t0 = time.perf_counter()
    s = SessionState(text, SCENARIO.stem, verify=False)
    out = {"open": time.perf_counter() - t0, "replan": [], "cpu": []}
    t0 = time.perf_counter()
    s.plan({})
    out["plan"] = time.perf_counter() - t0
    for r in requests:
        t0, c0 = time.perf_counter(), time.process_time()
        s.replan(r)
        out["replan"].append(time.perf_counter() - t0)
        out["cpu"].append(time.process_time() - c0)
    return out


def measure_loops(address: str, text: str, loops: int, budget: float) -> dict:
    """``loops`` closed loops each way, alternating; no new loop once ``budget`` s have passed."""
    from pushplan.client import Client

    requests, reference = closed_loop_requests(text)
    service, local, t0 = [], [], time.perf_counter()
    with Client(address, timeout=600.0) as c:
        while len(service) < loops and (not service or time.perf_counter() - t0 < budget):
            service.append(_service_loop(c, requests))
            local.append(_local_loop(text, requests))
    same = all(run["commands"] == reference for run in service)
    replan_s = np.array([x for run in service for x in run["replan"]])
    replan_l = np.array([x for run in local for x in run["replan"]])
    parts = np.array([p for run in service for p in run["parts"]])  # server, session, session cpu, solve
    overhead = replan_s - replan_l
    steps = tomllib.loads(text)["plan"]["steps"]
    by_left = {str(steps - len(r["executed"])): _stats([run["cpu"][i] for run in local])
               for i, r in enumerate(requests)}  # where the tail is: the re-plans with the most pushes left
    return {
        "loops": len(service), "loops_asked": loops, "loop_budget_s": budget,
        "replans_per_loop": len(requests), "answers_equal_to_the_first_loop": same,
        "open": _stats([r["open"] for r in service]), "open_in_process": _stats([r["open"] for r in local]),
        "plan": _stats([r["plan"] for r in service]), "plan_in_process": _stats([r["plan"] for r in local]),
        "warm_replan": _stats(replan_s), "warm_replan_in_process": _stats(replan_l),
        "warm_replan_in_process_cpu": _stats([x for run in local for x in run["cpu"]]),
        "warm_replan_cpu_by_pushes_left": by_left,
        "warm_replan_session_cpu": _stats(parts[:, 2]),
        "warm_replan_overhead": _stats(overhead),
        "warm_replan_wire": _stats(replan_s - parts[:, 1]),
        "warm_replan_ratio_median": float(np.median(replan_s) / np.median(replan_l)),
        "warm_replan_wire_parts_median_s": {
            "client_and_grpc_json": float(np.median(replan_s - parts[:, 0])),
            "server_to_session_pipe": float(np.median(parts[:, 0] - parts[:, 1]))},
    }


def measure_verified(address: str, text: str, loops: int, budget: float) -> dict:
    """The default ``Replan`` (verified on the verification mesh) in sessions opened with
    ``verify`` true, ``loops`` closed loops' requests at most, none started once ``budget`` s
    have passed: wall times from this process, the session's CPU, FE rollouts, by pushes left."""
    from pushplan.client import Client

    requests, _ = closed_loop_requests(text)
    steps = tomllib.loads(text)["plan"]["steps"]
    runs, t_start = [], time.perf_counter()
    with Client(address, timeout=600.0) as c:
        while len(runs) < loops and (not runs or time.perf_counter() - t_start < budget):
            t0 = time.perf_counter()
            s = c.open(scenario_path=str(SCENARIO))  # verify: true, the default
            run = {"open": time.perf_counter() - t0, "replan": [], "cpu": [], "rollouts": [], "commands": []}
            t0 = time.perf_counter()
            s.plan()
            run["plan"] = time.perf_counter() - t0
            for r in requests:
                t0 = time.perf_counter()
                answer = s.replan(r["executed"], r["observed"])  # closed_loop false: verified
                run["replan"].append(time.perf_counter() - t0)
                run["cpu"].append(answer["session_cpu_s"])
                run["rollouts"].append(answer["fe_rollouts"])
                run["commands"].append(answer["commands"])
            s.close()
            runs.append(run)
    left = [str(steps - len(r["executed"])) for r in requests]
    return {
        "verified_loops": len(runs), "verified_loops_asked": loops, "verified_budget_s": budget,
        "verified_mesh": "verification 12 x 12 x 4, quadrature 3 (and the planning mesh)",
        "verified_answers_equal_to_the_first_loop": all(r["commands"] == runs[0]["commands"] for r in runs),
        "verified_open": _stats([r["open"] for r in runs]), "verified_plan": _stats([r["plan"] for r in runs]),
        "verified_replan": _stats([x for r in runs for x in r["replan"]]),
        "verified_replan_session_cpu": _stats([x for r in runs for x in r["cpu"]]),
        "verified_replan_by_pushes_left": {k: _stats([r["replan"][i] for r in runs]) for i, k in enumerate(left)},
        "verified_replan_fe_rollouts_by_pushes_left": {k: runs[0]["rollouts"][i] for i, k in enumerate(left)},
    }


def measure_rollouts(address: str, text: str, calls: int, budget: float) -> dict:
    """``calls`` rollouts each way, alternating; none started once ``budget`` s have passed."""
    from pushplan.client import Client
    from pushplan.service.worker import SessionState

    local = SessionState(text, SCENARIO.stem, verify=False)
    service, here, session = [], [], []
    with Client(address, timeout=600.0) as c:
        s = c.open(scenario_path=str(SCENARIO), verify=False)
        t_start = time.perf_counter()
        while len(service) < calls and (not service or time.perf_counter() - t_start < budget):
            t0 = time.perf_counter()
            a = s.rollout(COMMANDS)
            service.append(time.perf_counter() - t0)
            session.append(a["session_s"])
            t0 = time.perf_counter()
            b = local.rollout({"commands": COMMANDS})
            here.append(time.perf_counter() - t0)
        s.close()
    return {"rollout_budget_s": budget, "rollout_3_pushes_6x6x2": _stats(service), "rollout_in_process": _stats(here),
            "rollout_overhead": _stats(np.array(service) - np.array(here)),
            "rollout_wire": _stats(np.array(service) - np.array(session)),
            "rollout_ratio_median": float(np.median(service) / np.median(here)),
            "rollout_answers_equal": a["poses"] == b["poses"]}


def _client_run(address: str, requests: list[dict], i: int, replans: int) -> list:
    """One client's session: plan, the loop's pushes but the last, then ``replans`` re-plans
    of the last push with observation ``i`` (its own: x and y off by ``i`` um)."""
    from pushplan.client import Client

    last = requests[-1]
    observed = [last["observed"][0] + 1e-6 * i, last["observed"][1] - 1e-6 * i, last["observed"][2]]
    with Client(address, timeout=600.0) as c:
        s = c.open(scenario_path=str(SCENARIO), verify=False)
        answers = [s.plan()["commands"]]
        for _ in range(replans):
            answers.append(s.replan(last["executed"], observed)["commands"])
        s.close()
    return answers


def measure_isolation(address: str, text: str, clients: int, replans: int) -> dict:
    requests, _ = closed_loop_requests(text)
    singles = [_client_run(address, requests, i, replans) for i in range(clients)]
    t0 = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(clients) as pool:
        together = pool.starmap(_client_run, [(address, requests, i, replans) for i in range(clients)])
    wall = time.perf_counter() - t0
    diff = max(float(np.max(np.abs(np.array(a) - np.array(b)))) for x, y in zip(singles, together, strict=True)
               for a, b in zip(x, y, strict=True))
    return {"clients": clients, "replans_each": replans, "wall_s": wall,
            "max_abs_difference_from_single_client_m": diff,
            "distinct_final_answers": len({json.dumps(x[-1]) for x in together}), "all_equal": diff == 0.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=40, help="closed loops (5 re-plans each) per path, at most")
    ap.add_argument("--loop-budget", type=float, default=90.0, help="s after which no new loop starts")
    ap.add_argument("--verified-loops", type=int, default=8, help="closed loops of verified re-plans, at most")
    ap.add_argument("--verified-budget", type=float, default=60.0, help="s after which no new verified loop starts")
    ap.add_argument("--calls", type=int, default=200, help="rollouts per path, at most")
    ap.add_argument("--rollout-budget", type=float, default=20.0, help="s after which no new rollout starts")
    ap.add_argument("--idle", type=float, default=5.0)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--replans", type=int, default=50)
    ap.add_argument("--quick", action="store_true", help="3 loops, 20 rollouts, 2 clients x 3 re-plans")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "serve_latency.json"))
    args = ap.parse_args(argv)
    if args.quick:
        args.loops, args.calls, args.idle, args.clients, args.replans = 3, 20, 1.0, 2, 3
        args.verified_loops = 1
    from pushplan.client import Client

    t_start, load_before = time.perf_counter(), os.getloadavg()
    text = SCENARIO.read_text()
    server = subprocess.Popen([sys.executable, "-m", "pushplan.cli", "serve", "--address", "127.0.0.1:0",
                               "--root", str(SCENARIO.parent), "--max-sessions", str(max(args.clients, 2))],
                              stdout=subprocess.PIPE, text=True)
    from _common import machine_info

    doc = {"machine": machine_info(), "scenario": SCENARIO.name, "mesh": "planning 6 x 6 x 2, quadrature 2",
           "server": "pushplan serve, its own process; the client this process", "cores": os.cpu_count()}
    try:
        address = server.stdout.readline().split("listening on ")[1].strip()
        doc |= measure_loops(address, text, args.loops, args.loop_budget)
        doc |= measure_verified(address, text, args.verified_loops, args.verified_budget)
        doc |= measure_rollouts(address, text, args.calls, args.rollout_budget)
        with Client(address) as c:
            s = c.open(scenario_path=str(SCENARIO), verify=False)
            trips = []
            for _ in range(args.calls):  # the wire alone: a session's Info does no work
                t0 = time.perf_counter()
                s.state()
                trips.append(time.perf_counter() - t0)
            doc["session_info_round_trip"] = _stats(trips)
            cpu0, t0 = _tree_cpu(server.pid), time.perf_counter()
            time.sleep(args.idle)  # the measured interval itself: the server's CPU while nobody calls
            doc["server_idle_cpu_s_per_s"] = (_tree_cpu(server.pid) - cpu0) / (time.perf_counter() - t0)
            doc["server_idle_resolution_s_per_s"] = 1.0 / os.sysconf("SC_CLK_TCK") / args.idle  # one clock tick
            s.close()
        doc["isolation"] = measure_isolation(address, text, args.clients, args.replans)
        # the CPU the whole run took (at idle on 2 cores its wall time is about half of it)
        own = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        doc["cpu_s"] = {"client_and_its_children": sum(r.ru_utime + r.ru_stime for r in own),
                        "server_tree": _tree_cpu(server.pid)}
    finally:
        server.terminate()
        doc["server_exit"] = server.wait(60)
    doc["load_average_before"], doc["load_average_after"] = load_before, os.getloadavg()
    doc["benchmark_wall_s"] = time.perf_counter() - t_start
    print(json.dumps(doc, indent=1))
    _summary(doc)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


def _summary(doc: dict) -> None:
    ms = 1e3
    for key in ("open", "plan", "warm_replan", "rollout_3_pushes_6x6x2"):
        here = "rollout_in_process" if key.startswith("rollout") else f"{key}_in_process"
        a, b = doc[key], doc[here]
        print(f"{key:>24}: service {a['median_s'] * ms:8.1f} / {a['p99_s'] * ms:8.1f} ms (median / p99 of {a['calls']}),"
              f" in process {b['median_s'] * ms:8.1f} / {b['p99_s'] * ms:8.1f} ms")
    v = doc["verified_replan"]
    print(f"verified re-plan (default Replan, verify true): service {v['median_s'] * ms:.1f} / {v['p99_s'] * ms:.1f} ms "
          f"(median / p99 of {v['calls']}), by pushes left " + ", ".join(
              f"{k}: {x['median_s'] * ms:.0f} ms" for k, x in doc["verified_replan_by_pushes_left"].items()))
    o, w, parts = doc["warm_replan_overhead"], doc["warm_replan_wire"], doc["warm_replan_wire_parts_median_s"]
    print(f"warm re-plan: service - in process per call (pairs) median {o['median_s'] * ms:.2f} ms, p99 "
          f"{o['p99_s'] * ms:.2f} ms; the wire (client time - session time, same call) median {w['median_s'] * ms:.2f} ms,"
          f" p99 {w['p99_s'] * ms:.2f} ms: " + ", ".join(f"{k} {v * ms:.2f} ms" for k, v in parts.items()))
    print("warm re-plan in process, CPU median / max by pushes left: " + ", ".join(
        f"{k}: {v['median_s'] * ms:.1f} / {v['max_s'] * ms:.1f} ms" for k, v in doc["warm_replan_cpu_by_pushes_left"].items()))
    print(f"rollout: the wire median {doc['rollout_wire']['median_s'] * ms:.2f} ms, p99 "
          f"{doc['rollout_wire']['p99_s'] * ms:.2f} ms; a session's Info (no work) round trip median "
          f"{doc['session_info_round_trip']['median_s'] * ms:.2f} ms, p99 {doc['session_info_round_trip']['p99_s'] * ms:.2f} ms")
    print(f"rollout ratio {doc['rollout_ratio_median']:.3f}, re-plan ratio {doc['warm_replan_ratio_median']:.3f}; "
          f"server idle CPU {doc['server_idle_cpu_s_per_s']:.4f} s/s; isolation all equal "
          f"{doc['isolation']['all_equal']}; load average {doc['load_average_before'][0]:.1f} -> "
          f"{doc['load_average_after'][0]:.1f} on {doc['cores']} cores; {doc['benchmark_wall_s']:.0f} s wall, CPU "
          f"{doc['cpu_s']['client_and_its_children']:.0f} s client + {doc['cpu_s']['server_tree']:.0f} s server")


if __name__ == "__main__":
    sys.exit(main())
