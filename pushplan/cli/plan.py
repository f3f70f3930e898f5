"""``pushplan plan SCENARIO --out DIR``: plan the ``[plan]`` table's commands, write
``plan.json`` (and ``recording.rrd``), print the final errors.

Exit status 3 for a plan not within tolerance (the best verified plan is written) and,
through :func:`pushplan.cli.main`, for a failed FE rollout (``PlanningError``); 2 for
bad input (nothing written).
"""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE


def _describe(e: dict) -> str:
    """A ``final_error`` entry of ``plan.json`` in mm, % of travel and degrees."""
    rel = f" ({100 * e['position_rel_travel']:.3f} % of travel)" if e["position_rel_travel"] is not None else ""
    yaw = f", yaw {e['yaw_deg']:.4f} deg" if e["yaw_deg"] is not None else ""
    return f"{e['position'] * 1e3:.5f} mm{rel}{yaw}"


def cmd_plan(args) -> int:
    from ..config import load_scenario
    from ..config.plan import parse_plan
    from ..outputs import atomic_write_json, prepare_output_dir
    from ..planning import plan, plan_document, write_recording

    scenario = load_scenario(args.scenario)
    spec = parse_plan(scenario)
    out = prepare_output_dir(args.out)

    def log(text):
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    result = plan(scenario, spec, log=log)
    doc = plan_document(result)
    atomic_write_json(out / "plan.json", doc)
    wrote = [out / "plan.json"]
    if not args.no_recording:
        write_recording(result, out / "recording.rrd", scenario.model())
        wrote.append(out / "recording.rrd")
    print(f"{scenario.name}: {result.status} ({result.message})")
    state = spec.target_state
    print(f"  target: the lower-face pose {'at rest after the release' if state == 'rest' else 'under load'}")
    for name in ("loaded", "rest"):
        plan_pose, naive_pose = doc["final_poses"][name], doc["naive"]["final_poses"][name]
        if plan_pose is None:
            continue
        mark = " (the target's)" if name == state else ""
        print(f"  planned error {name:>6}{mark} (FE, verification mesh): {_describe(plan_pose['error'])}")
        print(f"  naive error   {name:>6}{mark} (FE, verification mesh): {_describe(naive_pose['error'])}")
    print(f"  FE rollouts: planning {result.rollouts['planning']}, verification {result.rollouts['verification']}; "
          f"plan time {result.timings['total']:.2f} s")
    print("  wrote " + ", ".join(str(p) for p in wrote))
    if result.status in ("infeasible", "not_converged"):
        print(f"pushplan: {result.message}", file=sys.stderr)
    return EXIT_SOLVER_FAILURE if result.status == "not_converged" else 0


def register(subparsers) -> None:
    """Add the ``plan`` subcommand."""
    p = subparsers.add_parser("plan", help="plan upper-face commands reaching a target pose ([plan] table)")
    p.add_argument("scenario", help="scenario TOML file with a [plan] table")
    p.add_argument("--out", required=True, help="output folder (plan.json, recording.rrd)")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_plan)
