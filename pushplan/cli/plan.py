"""``pushplan plan SCENARIO --out DIR``: plan the ``[plan]`` table's commands, write
``plan.json`` (and ``recording.rrd``), print the final errors.

Exit status 3 for a plan not within tolerance (the best verified plan is written) and,
through :func:`pushplan.cli.main`, for a failed FE rollout (``PlanningError``); 2 for
bad input (nothing written).
"""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE
from .simulate import add_memory_flag


def _describe(e: dict) -> str:
    """A ``final_error`` entry of ``plan.json`` in mm, % of travel and degrees."""
    rel = f" ({100 * e['position_rel_travel']:.3f} % of travel)" if e["position_rel_travel"] is not None else ""
    yaw = f", yaw {e['yaw_deg']:.4f} deg" if e["yaw_deg"] is not None else ""
    return f"{e['position'] * 1e3:.5f} mm{rel}{yaw}"


def _verification_error(scenario, doc: dict, ratio: float) -> dict:
    """The GCI of the verification mesh for the plan's commands (``plan.json``'s
    ``verification_error``): lower-face x, y, yaw on that mesh and two coarser ones."""
    import math

    from ..config.commands import commands_from_list
    from ..studies.convergence import verification_error

    result = verification_error(scenario, commands_from_list(doc["commands"]), ratio)
    pose = {k: result.extrapolated[k].to_dict() for k in ("lower_x", "lower_y", "lower_yaw_deg")
            } if result.extrapolated else {}
    gx, gy = (pose.get(k, {}).get("gci_abs") for k in ("lower_x", "lower_y"))
    return {"ratio": ratio, "levels": [lv.to_dict() for lv in result.levels], "extrapolated": pose,
            "position_gci": math.hypot(gx, gy) if gx is not None and gy is not None else None}


def cmd_plan(args) -> int:
    from ..config import load_scenario
    from ..config.plan import parse_plan
    from ..config.budget import check_memory
    from ..outputs import atomic_write_json
    from ..outputs.transaction import output_transaction
    from ..planning import plan, plan_document, write_recording

    scenario = load_scenario(args.scenario)
    spec = parse_plan(scenario)
    check_memory(scenario.elements, scenario.quadrature, override=args.no_memory_check)
    tx = output_transaction(args.out, ("plan.json", "recording.rrd"))

    def log(text):
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    with tx:
        result = plan(scenario, spec, log=log)
        doc = plan_document(result)
        if args.verification_error:
            doc["verification_error"] = _verification_error(scenario, doc, args.verification_ratio)
        atomic_write_json(tx.path / "plan.json", doc)
        wrote = [tx.out / "plan.json"]
        if not args.no_recording:
            write_recording(result, tx.path / "recording.rrd", scenario.model())
            wrote.append(tx.out / "recording.rrd")
    print(f"{scenario.name}: {result.status} ({result.message})")
    print(f"  planned final error (FE, verification mesh): {_describe(doc['final_error'])}")
    print(f"  naive final error   (FE, verification mesh): {_describe(doc['naive']['final_error'])}")
    if args.verification_error:
        ve = doc["verification_error"]
        gci = "no monotone sequence" if ve["position_gci"] is None else f"{ve['position_gci'] * 1e3:.5f} mm"
        print(f"  verification mesh error (GCI of {list(scenario.elements)} from "
              f"{[lv['elements'] for lv in ve['levels']]}): position {gci}")
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
    p.add_argument("--verification-error", action="store_true",
                   help="also run the plan on two coarser meshes and state the GCI of the verification mesh "
                   "(plan.json: verification_error)")
    p.add_argument("--verification-ratio", type=float, default=1.5,
                   help="coarsening ratio of those meshes (default 1.5)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_memory_flag(p)
    p.set_defaults(func=cmd_plan)
