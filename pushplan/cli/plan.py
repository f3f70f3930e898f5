"""``pushplan plan SCENARIO --out DIR``: plan the ``[plan]`` table's commands, write
``plan.json`` (and ``recording.rrd``), print the final errors.

With ``--identified identified.json`` the plan is robust (:mod:`pushplan.planning.robust`):
planned for the identified estimate, then refined to reach ``[plan] robust.level``, the
probability of the final pose within tolerance over the identified distribution, and
checked by a Monte Carlo of FE rollouts (``plan.json``: ``robust``).

Exit status 3 for a plan not within tolerance (the best verified plan is written), a robust
plan below its level (the commands of the highest probability found are written) and,
through :func:`pushplan.cli.main`, for a failed FE rollout (``PlanningError``); 2 for
bad input (nothing written).
"""

from __future__ import annotations

import sys
from contextlib import nullcontext

from ..errors import EXIT_SOLVER_FAILURE
from .simulate import add_memory_flag

REFINEMENTS = ("modifier", "exact_gradient")
DEFAULT_REFINEMENT = "modifier"
"""``--refinement``: :data:`pushplan.planning.planner.REFINEMENTS` and its default, written
here so that ``pushplan --help`` does not import the planner (a test checks they agree)."""


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


def _world_frame(path):
    """(scenario, origin) for ``[plan] frame = "world"``: the scenario as the ``[mujoco]``
    scene gives it and the block's rest pose there (lower-face centre x, y in m, yaw in rad)."""
    from ..mujoco.scene import open_scene

    scene, _ = open_scene(path)
    return scene.scenario, (float(scene.lower_centre[0]), float(scene.lower_centre[1]), scene.yaw)


def _world_poses(doc: dict, spec) -> dict:
    """``plan.json``'s ``world`` entry: target, origin and the verified poses in the world
    frame (rows ``[x (m), y (m), yaw (deg)]``; yaw the block's world yaw)."""
    import math

    from ..config.plan import block_to_world

    def row(pose):
        x, y, yaw = block_to_world((pose[0], pose[1], math.radians(pose[2])), spec.world_origin)
        return [x, y, math.degrees(yaw)]

    verified = [row(p) for p in doc["poses"]["verified"]]
    return {**doc["plan"]["world"], "verified": verified, "verified_final": verified[-1],
            "naive_final": None if doc["naive"] is None else row(doc["naive"]["verified_poses"][-1])}


def _print_robust(r: dict) -> None:
    """The robust plan's promise and its check, beside the nominal plan's."""
    mc = r["monte_carlo"]
    for name, predicted in (("robust", r["predicted_probability"]), ("nominal", r["nominal_predicted_probability"])):
        check = mc.get(name)
        seen = ("" if not check or not check["count"] else
                f"; Monte Carlo {check['within_tolerance']}/{check['count']} = {check['fraction']:.3f} within tolerance "
                f"(95 % interval [{check['interval_95'][0]:.3f}, {check['interval_95'][1]:.3f}])")
        print(f"  {name:>7} plan: predicted probability within tolerance {predicted:.4f}{seen}")
    n = r["fe_rollouts"]
    print(f"  robust: {n['sigma_points']} sigma points, {n['sigma_point_rollouts']} sigma-point FE rollouts, "
          f"{n['monte_carlo_rollouts']} Monte Carlo FE rollouts (level {r['level']:g}: "
          f"{'reached' if r['reached'] else 'not reached'})")


def _print_summary(scenario, spec, result, doc: dict, wrote, args) -> None:
    """The plan's status, final errors (planned and naive, loaded and at rest), the robust
    check and what was written, on stdout."""
    print(f"{scenario.name}: {result.status} ({result.message})")
    state = spec.target_state
    print(f"  target: the lower-face pose {'at rest after the release' if state == 'rest' else 'under load'}")
    for name in ("loaded", "rest"):
        plan_pose = doc["final_poses"][name]
        if plan_pose is None:
            continue
        mark = " (the target's)" if name == state else ""
        print(f"  planned error {name:>6}{mark} (FE, verification mesh): {_describe(plan_pose['error'])}")
        if doc["naive"] is not None:
            naive_pose = doc["naive"]["final_poses"][name]
            print(f"  naive error   {name:>6}{mark} (FE, verification mesh): {_describe(naive_pose['error'])}")
    if spec.world_origin is not None:
        x, y, yaw = doc["world"]["verified_final"]
        print(f"  verified final pose (world frame): x {x * 1e3:.5f} mm, y {y * 1e3:.5f} mm, yaw {yaw:.4f} deg")
    if args.verification_error:
        ve = doc["verification_error"]
        gci = "no monotone sequence" if ve["position_gci"] is None else f"{ve['position_gci'] * 1e3:.5f} mm"
        print(f"  verification mesh error (GCI of {list(scenario.elements)} from "
              f"{[lv['elements'] for lv in ve['levels']]}): position {gci}")
    print(f"  FE rollouts: planning {result.rollouts['planning']}, verification {result.rollouts['verification']} "
          f"(refinement: {result.refinement}); plan time {result.timings['total']:.2f} s")
    if "robust" in doc:
        _print_robust(doc["robust"])
    print("  wrote " + ", ".join(str(p) for p in wrote))


def _inputs(args):
    """The checked inputs of ``plan``: ``(scenario, spec, distribution, start, full_spec)``;
    the scenario at the identified estimate with ``--identified`` (``distribution`` else
    None), ``start`` the measured start with ``--from`` (``spec`` its remaining steps,
    ``full_spec`` the table's; else None and ``spec``).

    Raises
    ------
    InputError
        A bad scenario, ``[plan]`` table, identified file or observation file; both
        ``--identified`` and ``--from``; a mesh over the memory budget.
    """
    from ..config import load_scenario
    from ..config.budget import check_memory
    from ..config.plan import parse_plan
    from ..errors import InputError

    scenario, origin = load_scenario(args.scenario), None
    table = scenario.extra.get("plan")
    if isinstance(table, dict) and table.get("frame") == "world":
        scenario, origin = _world_frame(args.scenario)
    distribution = None
    if args.identified:
        from ..identify.document import read_identified

        if args.from_observations:
            raise InputError("--identified: a robust plan re-planned --from observations is not supported; "
                             "give one of them")
        distribution = read_identified(args.identified)
        scenario = distribution.scenario(scenario, distribution.mean)  # the nominal plan is for the estimate
    spec = full_spec = parse_plan(scenario, world_origin=origin)
    start = None
    if args.from_observations:
        from ..config.observations import read_observations
        from ..planning.replan import measured_start, remaining_spec

        start = measured_start(scenario, spec, read_observations(args.from_observations))
        spec = remaining_spec(spec, start)
    check_memory(scenario.elements, scenario.quadrature, override=args.no_memory_check)
    check_memory(spec.planning_elements, spec.planning_quadrature, override=args.no_memory_check,
                 what="plan.planning_elements")
    return scenario, spec, distribution, start, full_spec


def _planned(args, scenario, spec, distribution, start, log):
    """``(result, robust)``: the plan (the robust one with ``distribution``) and the
    :class:`~pushplan.planning.robust.RobustResult` (None without ``--identified``)."""
    from ..planning import plan

    result = plan(scenario, spec, log=log, after=start.executed if start else (), baseline=not args.no_baseline,
                  refinement=args.refinement)
    if distribution is None:
        return result, None
    from ..planning.robust import plan_robust

    robust = plan_robust(scenario, distribution, spec, result, log=log)
    return robust.result, robust


def _document(args, scenario, spec, result, robust, start, full_spec) -> dict:
    """The ``plan.json`` content: the plan, its robust check, world poses, the measured start, the GCI."""
    from ..planning import plan_document

    doc = plan_document(result)
    if robust is not None:
        from ..planning.robust import robust_document

        doc["robust"] = robust_document(robust, spec)
    if spec.world_origin is not None:
        doc["world"] = _world_poses(doc, spec)
    if start is not None:  # poses are relative to the observed pose; plan is the remaining steps' spec
        doc["from"] = {"observations": args.from_observations, **start.to_dict(), "full_plan": full_spec.to_dict()}
    if args.verification_error:
        doc["verification_error"] = _verification_error(scenario, doc, args.verification_ratio)
    return doc


def cmd_plan(args) -> int:
    from ..outputs import atomic_write_json
    from ..outputs.recording_process import RecordingProcess
    from ..outputs.transaction import output_transaction
    from ..planning.document import recording_job

    scenario, spec, distribution, start, full_spec = _inputs(args)
    tx = output_transaction(args.out, ("plan.json", "recording.rrd"))

    def log(text):
        if not args.quiet:
            print(text, file=sys.stderr, flush=True)

    # the recording's writer imports rerun on the other core while this process plans
    writer = RecordingProcess() if not args.no_recording else nullcontext()
    with writer, tx:
        result, robust = _planned(args, scenario, spec, distribution, start, log)
        doc = _document(args, scenario, spec, result, robust, start, full_spec)
        atomic_write_json(tx.path / "plan.json", doc)
        wrote = [tx.out / "plan.json"]
        if not args.no_recording:
            fn, job = recording_job(result, tx.path / "recording.rrd", scenario.mesh())
            writer.run(fn, *job)
            wrote.append(tx.out / "recording.rrd")
    _print_summary(scenario, spec, result, doc, wrote, args)
    if result.status in ("infeasible", "not_converged"):
        print(f"pushplan: {result.message}", file=sys.stderr)
    return EXIT_SOLVER_FAILURE if result.status == "not_converged" else 0


def register(subparsers) -> None:
    from ..limits import MAX_RATIO
    from .args import real

    """Add the ``plan`` subcommand."""
    p = subparsers.add_parser("plan", help="plan upper-face commands reaching a target pose ([plan] table)")
    p.add_argument("scenario", help="scenario TOML file with a [plan] table")
    p.add_argument("--out", required=True, help="output folder (plan.json, recording.rrd)")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--no-baseline", action="store_true",
                   help="do not roll the naive commands out on the verification mesh (plan.json: naive is null)")
    p.add_argument("--from", dest="from_observations", metavar="OBSERVATIONS",
                   help="re-plan the remaining steps from the last observed pose of this observation file (.csv or "
                   ".json: the press and the pushes executed so far); poses in plan.json are then relative to it")
    p.add_argument("--verification-error", action="store_true",
                   help="also run the plan on two coarser meshes and state the GCI of the verification mesh "
                   "(plan.json: verification_error)")
    p.add_argument("--verification-ratio", type=real(1.0, MAX_RATIO), default=1.5,
                   help=f"coarsening ratio of those meshes (> 1, at most {MAX_RATIO}; default 1.5)")
    p.add_argument("--refinement", choices=REFINEMENTS, default=DEFAULT_REFINEMENT,
                   help="FE correction of the plan: modifier adaptation, or Gauss-Newton steps with the exact "
                   "gradient (modifier adaptation where a release or a frictional pad has no derivatives); "
                   f"default {DEFAULT_REFINEMENT}")
    p.add_argument("--identified", metavar="IDENTIFIED_JSON",
                   help="plan robustly over the parameter distribution of this identified.json (pushplan identify): "
                   "the estimate replaces the scenario's values, [plan] robust sets the level and the Monte Carlo "
                   "check (docs/planning.md)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_memory_flag(p)
    p.set_defaults(func=cmd_plan)
