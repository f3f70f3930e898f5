"""``pushplan simulate SCENARIO --out DIR``: run the load steps, print the step table."""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE, InputError


RUN_FILES = ("summary.json", "fields.npz", "recording.rrd")
"""What ``simulate`` writes in ``--out`` (a previous run's files of these names are not kept)."""
FCLIB_FILES = ("step_*.hdf5",)


def add_memory_flag(parser) -> None:
    """``--no-memory-check``: run even when the estimated memory exceeds what is available."""
    parser.add_argument("--no-memory-check", action="store_true",
                        help="run even if the estimated memory of the model exceeds the available memory")


def print_steps(steps) -> None:
    """The step table of :class:`~pushplan.run.StepSummary` rows (mm, degrees, kN)."""
    print(f"{'step':>4} {'upper x,y (mm)':>18} {'lower x,y (mm)':>18} {'twist':>8} {'yaw':>8} "
          f"{'N (kN)':>9} {'max slip':>9} {'newton':>6} {'contact':>7}")
    for s in steps:
        u, lo = s.upper_centroid, s.lower_centroid
        print(f"{s.step:>4} {u[0]*1e3:>8.4f},{u[1]*1e3:>8.4f} {lo[0]*1e3:>8.4f},{lo[1]*1e3:>8.4f} "
              f"{s.twist_deg:>7.3f}° {s.lower_yaw_deg:>7.4f}° {s.normal_force/1e3:>9.2f} "
              f"{s.max_slip*1e3:>7.4f}mm {s.newton_iterations:>6} {s.contact_iterations:>7}")


def exit_status(run) -> int:
    """0 for a completed run; otherwise the failure on stderr and :data:`EXIT_SOLVER_FAILURE`."""
    if not run.completed:
        print(f"pushplan: solver failure: {run.summary.failure.message}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def cmd_simulate(args) -> int:
    from ..config import load_scenario
    from ..config.commands import read_command_file
    from ..config.fingerprint import check_plan_scenario
    from contextlib import nullcontext

    from ..outputs.transaction import output_transaction
    from ..run import simulate
    from ..config.budget import check_memory

    scenario = load_scenario(args.scenario)
    commands = None
    if args.commands is not None:
        commands, document = read_command_file(args.commands)
        check_plan_scenario(document, scenario.to_dict(), args.commands, force=args.force)
    if not (scenario.commands if commands is None else commands):
        raise InputError(f"nothing to simulate: no load steps in {args.commands or args.scenario}")
    check_memory(scenario.elements, scenario.quadrature, override=args.no_memory_check)
    model = scenario.model()  # mesh and material checks before anything is written
    out = output_transaction(args.out, RUN_FILES)
    fclib = output_transaction(args.export_fclib, FCLIB_FILES) if args.export_fclib else nullcontext()
    with out, fclib:
        run = simulate(scenario, out.path, commands=commands, model=model, progress=not args.quiet,
                       recording=not args.no_recording, export_fclib=fclib.path if args.export_fclib else None)
    print_steps(run.summary.steps)
    print(f"wrote {out.out / 'summary.json'} and {out.out / 'fields.npz'} ({run.summary.elapsed_s:.2f} s)")
    return exit_status(run)


def register(subparsers) -> None:
    p = subparsers.add_parser("simulate", help="run a scenario's load steps through the FE model")
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder (summary.json, fields.npz)")
    p.add_argument("--commands", help="plan.json whose upper-face commands replace the scenario's [[load]]")
    p.add_argument("--force", action="store_true",
                   help="run the --commands of a plan made for another scenario (block, material, friction, [plan])")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--export-fclib", metavar="DIR",
                   help="write each step's last local contact problem to DIR/step_NNN.hdf5 (FCLIB)")
    add_memory_flag(p)
    p.set_defaults(func=cmd_simulate)
