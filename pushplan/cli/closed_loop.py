"""``pushplan closed-loop SCENARIO --truth TRUTH.toml --out DIR [--identify]``: execute
the plan of SCENARIO one push at a time on TRUTH (the same block on other friction),
observe, re-identify (``--identify``), re-plan; compare with the open-loop plan.
With ``--identify`` and a ``[plan] robust`` table each re-plan is robust
(:mod:`pushplan.planning.robust`) over the re-identified estimate and covariance, and
``closed_loop.json`` records its predicted probability per re-plan.
Writes ``DIR/closed_loop.json`` (each iteration: command, observed pose, the planned
path behind it, the friction it was planned with, the estimates) and ``DIR/recording.rrd``
(the truth's closed-loop run; at each push ``plan/replanned``, the plan behind it; the
closed- and open-loop paths of the lower face as ``plan/verified`` / ``plan/naive``).

A rest target is scored on the truth's rest pose after its release; while that is outside the
tolerance the gripper grasps the block again where it rests and pushes the correction, up to
``[plan] episodes`` grasp-push-release cycles (``closed_loop.json``'s ``episodes``); an episode
that removes less than half of the error it started from stops them (``closed_loop.stop``,
:mod:`pushplan.identify.episodes`).  Exit status 3 when the closed loop ends outside the
tolerance, stops so, or a solver fails inside it (the files are
written when the loop finished); 2 for bad input (nothing written), checked before the
loop starts: a failure inside the loop is never 2 (a bug there exits 1 with its traceback).
"""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE

CLOSED_LOOP_FILES = ("closed_loop.json", "recording.rrd")
"""What ``closed-loop`` writes in ``--out`` (one transaction: no old recording beside a new JSON)."""


def _recording(path, scenario, runs, spec) -> None:
    import numpy as np

    from ..outputs.recording import Recorder

    closed, open_, planned = runs.closed, runs.open, runs.planned
    n_press = len(closed.steps) - len(planned)
    dims = 3 if spec.yaw_targeted else 2

    def path_of(t):
        return np.array([[s.lower_centroid[0], s.lower_centroid[1], s.lower_yaw] for s in t.steps])[:, :dims]

    with Recorder(path, f"closed_loop_{scenario.name}", closed.model.mesh, scenario=scenario.to_dict()) as rec:
        for i, (rep, summary) in enumerate(zip(closed.reports, closed.steps, strict=True)):
            rec.log_step(rep, summary)
            if i >= n_press:  # the plan behind this push
                rec.log_path("replanned", planned[i - n_press])
        rec.log_plan(target=np.array(spec.target)[:dims], verified=path_of(closed), naive=path_of(open_))


def cmd_closed_loop(args) -> int:
    from ..config import load_scenario
    from ..config.fingerprint import check_same_block
    from ..config.plan import parse_plan
    from ..identify import NoiseModel
    from ..identify.closed_loop import closed_loop
    from ..outputs import atomic_write_json
    from ..outputs.transaction import output_transaction

    scenario = load_scenario(args.scenario)
    spec = parse_plan(scenario)
    robust = "robust" in scenario.extra["plan"]  # [plan] robust set: robust re-plans with --identify
    truth = load_scenario(args.truth)
    check_same_block(scenario.to_dict(), truth.to_dict(), args.truth, force=args.force)
    truth.model()
    noise = NoiseModel(args.pose_noise, args.force_noise, args.force_noise_rel, force_resolution=args.force_resolution)
    log = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    with output_transaction(args.out, CLOSED_LOOP_FILES) as tx:
        result = closed_loop(scenario, truth, spec, args.identify, noise, log, robust=robust)
        doc = result.to_dict()
        atomic_write_json(tx.path / "closed_loop.json", doc)
        if not args.no_recording:
            _recording(tx.path / "recording.rrd", scenario, result.runs, spec)
    _print_summary(scenario, truth, spec, doc, tx.out)
    return 0 if result.within_tolerance and result.stopped is None else EXIT_SOLVER_FAILURE


def _print_summary(scenario, truth, spec, doc: dict, out) -> None:
    """The closed and open loop's final errors, the robust re-plans' probabilities and the estimates, on stdout."""
    c, o = doc["closed_loop"]["final_error"], doc["open_loop"]["final_error"]
    print(f"{scenario.name} on {truth.name}: closed loop {c['position'] * 1e6:.3f} um "
          f"({'within' if c['within_tolerance'] else 'outside'} tolerance {spec.tolerance * 1e6:.3g} um), "
          f"open loop {o['position'] * 1e6:.3f} um"
          + (f", {len(doc['episodes'])} episode(s)" if doc["episodes"] else ""))
    if doc["closed_loop"]["stopped"]:
        print("  " + doc["closed_loop"]["stopped"])
    probabilities = [it["predicted_probability"] for it in doc["iterations"] if it["robust"] is not None]
    if probabilities:
        print(f"  robust re-plans (level {spec.robust.level:g}): predicted probability "
              + ", ".join(f"{p:.3f}" for p in probabilities))
    if doc["final_estimates"]:
        print("  final estimates: " + ", ".join(f"{k} = {v['estimate']:.5g} +- {v['sigma'] or float('inf'):.2g}"
                                              for k, v in doc["final_estimates"].items() if k != "fe_rollouts"))
    print(f"  wrote {out / 'closed_loop.json'} ({doc['wall_time_s']:.1f} s)")


def register(subparsers) -> None:
    from .identify import add_noise_flags

    p = subparsers.add_parser("closed-loop", help="execute a plan push by push on a truth model, re-planning")
    p.add_argument("scenario", help="planning scenario TOML (the model; [plan] table)")
    p.add_argument("--truth", required=True, help="scenario TOML of the truth (same block, other friction)")
    p.add_argument("--out", required=True, help="output folder (closed_loop.json, recording.rrd)")
    p.add_argument("--identify", action="store_true", help="re-identify the friction after every push")
    p.add_argument("--force", action="store_true", help="run with a truth of another block size")
    add_noise_flags(p, yaw=False)
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_closed_loop)
