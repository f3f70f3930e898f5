"""Where the CPU time of a warm re-plan goes, per phase, with the planning mesh's rollout
steps started from the predictor (as before) and from the last rollout's converged steps
(:class:`fe_contact.StepGuess`, ``FeRollouts(warm_steps=True)``, what a session runs now),
in one process, one run, alternating loop by loop.

The case is ``benchmarks/serve_latency.py``'s: ``plan_rubber`` on its planning mesh
(6 x 6 x 2, a session without the verification mesh), ``Plan`` then the 5 warm re-plans of
the closed loop on the observations of a truth with 0.8 times the model's friction
(:func:`serve_latency.closed_loop_requests`, computed once each way: a re-plan's request
carries the pushes executed, the earlier answers' first commands, which differ between the
ways by rounding, and a push that is not bit for bit the last rollout's first costs an FE step).
Each re-plan is :meth:`pushplan.service.worker.SessionState.replan` (the session's code
without the wire); its process CPU time is split into the NLP (``ReducedPlanner.solve``),
the FE rollouts (``FeRollouts.rollout``), executing the pushes (``FeRollouts.advance``) and
the rest; per rollout the Newton iterations, the local contact solver's iterations and the
FE steps' own wall-time split (assembly, tangent, local contact solve, linear solves).
Medians over ``--repeat`` loops by pushes left.  Both ways' answers are compared (the
largest difference of the commands and of the planned poses, m) against how far the
predictor's own answers move when the FE tolerances ``newton_tol`` and ``local_tol`` go from
1e-10 to 1e-12, and the plan's tolerance.  CPU time is what a loaded machine inflates least;
the load average is recorded before and after.  Writes
``benchmarks/results/replan_phases.json``.

``--compare nlp`` compares instead the warm NLP solves (both with the rollout steps from the
last rollout): the full warm MPCC (``ReducedPlanner.active_set = False``) and the warm
start's active set first (:meth:`ReducedPlanner._solve_active_set`), each on its own
requests as above, and their answers once more on the same requests (the full MPCC's,
``answers_apart_on_the_same_requests``); writes ``replan_phases_nlp.json`` (``--name``: another).

    python benchmarks/replan_phases.py [--repeat 7] [--compare fe|nlp] [--name NAME]
"""

from __future__ import annotations

import argparse
import os
import time
import tomllib
from collections import defaultdict

import numpy as np

import fe_contact
from _common import write_results
from serve_latency import SCENARIO, closed_loop_requests
from pushplan.planning import nlp
from pushplan.planning.nlp import ReducedPlanner
from pushplan.planning.rollouts import FeRollouts
from pushplan.service.worker import SessionState

WAY_SETS = {"fe": {"from_predictor": (False, True), "from_last_rollout": (True, True)},
            "nlp": {"full_mpcc": (True, False), "active_set": (True, True)}}
"""The ways compared (``--compare``): (``FeRollouts.warm_steps``, ``ReducedPlanner.active_set``)."""
WAYS = tuple(WAY_SETS["fe"])
PHASES = ("nlp", "fe_rollouts", "advance")
FE_PARTS = ("assembly", "tangent", "local", "solve")


class _Meter:
    """CPU time per phase and the rollouts' iteration counts, by wrapping the phases' methods."""

    def __init__(self):
        self.cpu, self.counts, self.fe = defaultdict(float), defaultdict(int), defaultdict(float)
        self._originals = []

    def wrap(self, cls, name: str, phase: str) -> None:
        original = getattr(cls, name)
        meter = self

        def timed(*args, **kwargs):
            c0 = time.process_time()
            try:
                out = original(*args, **kwargs)
            finally:
                meter.cpu[phase] += time.process_time() - c0
            if phase == "fe_rollouts":
                meter.count(out.reports)
            elif phase == "nlp":
                meter.counts["nlp_iterations"] += out.iterations
            return out

        self._originals.append((cls, name, original))
        setattr(cls, name, timed)

    def count(self, reports) -> None:
        for r in reports:
            self.counts["fe_steps"] += 1
            self.counts["newton_iterations"] += r.newton_iterations
            self.counts["local_iterations"] += r.contact_iterations
            self.counts["tangents"] += r.tangent_updates
            for k in FE_PARTS:
                self.fe[k] += r.timings.get(k, 0.0)

    def take(self) -> dict:
        out = {"cpu_s": dict(self.cpu), "counts": dict(self.counts), "fe_step_wall_s": dict(self.fe)}
        self.cpu, self.counts, self.fe = defaultdict(float), defaultdict(int), defaultdict(float)
        return out

    def restore(self) -> None:
        for cls, name, original in reversed(self._originals):
            setattr(cls, name, original)


def _loop(text: str, requests: list[dict], way: tuple[bool, bool], meter: _Meter) -> list[dict]:
    """The closed loop in this process; per re-plan its phases, commands and poses."""
    ReducedPlanner.active_set = way[1]
    s = SessionState(text, SCENARIO.stem, verify=False)
    s.session.coarse.warm_steps = way[0]
    s.plan({})
    meter.take()
    rows = []
    for r in requests:
        c0 = time.process_time()
        answer = s.replan(r)
        total = time.process_time() - c0
        row = meter.take()
        row["cpu_s"]["total"] = total
        row["cpu_s"]["other"] = total - sum(row["cpu_s"].get(p, 0.0) for p in PHASES)
        row |= {"pushes_left": len(answer["commands"]), "commands": np.array(answer["commands"]),
                "poses": np.array(answer["poses"])}
        rows.append(row)
    return rows


def _median(rows: list[dict], key: str, names) -> dict:
    return {k: float(np.median([r[key].get(k, 0.0) for r in rows])) for k in names}


def _by_pushes_left(runs: dict) -> list[dict]:
    """One flat row per re-plan and way: medians over the loops (CPU s per phase, counts,
    the FE steps' wall s per part)."""
    out = []
    for i in range(len(runs[WAYS[0]][0])):
        for w in WAYS:
            rows = [loop[i] for loop in runs[w]]
            row = {"pushes_left": rows[0]["pushes_left"], "way": w}
            row |= {f"cpu_{k}_s": v for k, v in _median(rows, "cpu_s", ("total", *PHASES, "other")).items()}
            row |= _median(rows, "counts", ("fe_steps", "newton_iterations", "local_iterations", "tangents",
                                            "nlp_iterations"))
            row |= {f"fe_{k}_wall_s": v for k, v in _median(rows, "fe_step_wall_s", FE_PARTS).items()}
            out.append(row)
    return out


def _apart(a: list, b: list) -> float:
    """Largest difference (m) between two loops' answers, rows of commands or poses."""
    return float(max(np.abs(np.subtract(x, y)).max() for x, y in zip(a, b, strict=True)))


def answers_apart(text: str, runs: dict, ways: tuple[str, str], compare: str) -> dict:
    """How far the ways' answers are apart (largest over the re-plans, and per re-plan),
    against how far the first way's move when the FE tolerances (``newton_tol``,
    ``local_tol``; ``compare = "fe"``) or ipopt's ``tol`` (``"nlp"``) go from 1e-10 to 1e-12
    (one loop, untimed; ``"nlp"``: the full MPCC's from 1e-10 to 1e-12, the active-set
    NLP's from 1e-12 to 1e-13; ``""``: the difference alone)."""
    a, b = runs[ways[0]][0], runs[ways[1]][0]
    out = {"commands_m": _apart([x["commands"] for x in a], [y["commands"] for y in b]),
           "poses_m": _apart([x["poses"] for x in a], [y["poses"] for y in b]),
           "per_replan_commands_m": [_apart([x["commands"]], [y["commands"]]) for x, y in zip(a, b, strict=True)],
           "per_replan_poses_m": [_apart([x["poses"]], [y["poses"]]) for x, y in zip(a, b, strict=True)],
           "plan_tolerance_m": tomllib.loads(text)["plan"]["tolerance"]}
    if compare not in WAY_SETS:
        return out
    if compare == "fe":
        ReducedPlanner.active_set = True
        tight = text.replace('local_method = "newton"', 'local_method = "newton"\nnewton_tol = 1e-12\nlocal_tol = 1e-12')
        cold = closed_loop_requests(text, warm_steps=False)[1]
        out["predictor_commands_at_tolerances_1e-10_and_1e-12_m"] = _apart(
            cold, closed_loop_requests(tight, warm_steps=False)[1])
        return out
    for way in ways:
        ReducedPlanner.active_set = WAY_SETS["nlp"][way][1]
        loose = closed_loop_requests(text)[1]
        tols = nlp.SOLVER_OPTIONS["ipopt.tol"], nlp.ACTIVE_SET_OPTIONS["ipopt.tol"]
        nlp.SOLVER_OPTIONS["ipopt.tol"], nlp.ACTIVE_SET_OPTIONS["ipopt.tol"] = 1e-12, 1e-13
        try:
            out[f"{way}_commands_at_ipopt_tol_tightened_m"] = _apart(loose, closed_loop_requests(text)[1])
        finally:
            nlp.SOLVER_OPTIONS["ipopt.tol"], nlp.ACTIVE_SET_OPTIONS["ipopt.tol"] = tols
    return out


def _print(result: dict) -> None:
    ms = 1e3
    for r in result["by_pushes_left"]:
        print(f"{r['pushes_left']} pushes left, {r['way']:>17}: CPU {r['cpu_total_s'] * ms:6.1f} ms = NLP "
              f"{r['cpu_nlp_s'] * ms:5.1f} + FE rollouts {r['cpu_fe_rollouts_s'] * ms:5.1f} + advance "
              f"{r['cpu_advance_s'] * ms:4.1f} + other {r['cpu_other_s'] * ms:4.1f}; {r['fe_steps']:.0f} steps, "
              f"{r['newton_iterations']:.0f} Newton, {r['local_iterations']:.0f} local, {r['tangents']:.0f} tangents, "
              f"ipopt {r['nlp_iterations']:.0f} it")
    apart = result["answers_apart"]
    print("loop CPU median: " + ", ".join(f"{w} {v * ms:.1f} ms" for w, v in result["total_cpu_median_s"].items())
          + f"; answers apart: commands {apart['commands_m']:.2e} m, poses {apart['poses_m']:.2e} m ("
          + ", ".join(f"{k} {v:.2e}" for k, v in apart.items() if "tol" in k and "plan" not in k)
          + f"); load average {result['load_average_before'][0]:.1f} -> {result['load_average_after'][0]:.1f} on "
          f"{result['cpus']} cpus")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--compare", choices=tuple(WAY_SETS), default="fe",
                        help="fe: rollout steps from the predictor / the last rollout; nlp: the full warm "
                             "MPCC / the active-set NLP first (same requests, main's)")
    parser.add_argument("--name", default=None, help="results file name (default replan_phases[_nlp])")
    args = parser.parse_args(argv)
    ways = WAY_SETS[args.compare]
    global WAYS
    WAYS = tuple(ways)
    load_before = os.getloadavg()
    fe_contact.warm_up()
    text = SCENARIO.read_text()
    requests = {}
    for w, (warm_steps, active_set) in ways.items():  # each way's own requests (see the docstring)
        ReducedPlanner.active_set = active_set
        requests[w] = closed_loop_requests(text, warm_steps=warm_steps)[0]
    same = {}
    if args.compare == "nlp":  # both ways on the same requests (the first way's): their answers' difference
        for w, way in ways.items():
            same[w] = [_loop(text, requests[WAYS[0]], way, _Meter())]
    meter = _Meter()
    meter.wrap(ReducedPlanner, "solve", "nlp")
    meter.wrap(FeRollouts, "rollout", "fe_rollouts")
    meter.wrap(FeRollouts, "advance", "advance")
    runs = {w: [] for w in WAYS}
    try:
        for _ in range(args.repeat):
            for way in WAYS:
                runs[way].append(_loop(text, requests[way], ways[way], meter))
    finally:
        meter.restore()
        ReducedPlanner.active_set = True
    result = {
        "load_average_before": load_before, "cpus": os.cpu_count(), "repeat": args.repeat,
        "replans_per_loop": len(requests[WAYS[0]]), "by_pushes_left": _by_pushes_left(runs),
        "total_cpu_median_s": {w: float(np.median([sum(r["cpu_s"]["total"] for r in loop) for loop in runs[w]]))
                               for w in WAYS},
        "each_way_repeatable": all(_apart([x["commands"] for x in loop], [y["commands"] for y in runs[w][0]]) == 0.0
                                   for w in WAYS for loop in runs[w]),
        "compare": args.compare, "answers_apart": answers_apart(text, runs, WAYS, args.compare),
        "answers_apart_on_the_same_requests": answers_apart(text, same, WAYS, "") if same else None,
    }
    result["load_average_after"] = os.getloadavg()
    _print(result)
    if same:
        print("on the same requests: answers apart: commands {commands_m:.2e} m, poses {poses_m:.2e} m".format(
            **result["answers_apart_on_the_same_requests"]))
    name = args.name or ("replan_phases" if args.compare == "fe" else "replan_phases_nlp")
    print(f"wrote {write_results(name, result)}")


if __name__ == "__main__":
    main()
