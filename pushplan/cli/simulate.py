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
    """The step table of :class:`~pushplan.run.StepSummary` rows (mm, degrees, N); the
    lower face's direction deviation ("lower dev.", from the upper face's direction) is
    ``-`` while the lower face sticks (:func:`~pushplan.cli.units.deviation_text`); release
    steps are marked ``R``; with a frictional pad, its slip over the upper face ("pad slip")."""
    from .units import deviation_text, engineering

    pad = any(s.pad_slip is not None for s in steps)
    print(f"{'step':>5} {'upper x,y (mm)':>18} {'lower x,y (mm)':>18} {'lower dev.':>10} {'yaw':>9} "
          f"{'normal force':>12} {'max slip':>9}" + (f" {'pad slip':>9}" if pad else "") + f" {'newton':>6} {'contact':>7}")
    for s in steps:
        u, lo = s.upper_centroid, s.lower_centroid
        mark = "R" if s.phase == "release" else " "
        pad_text = "" if not pad else f" {s.pad_slip*1e3:>7.4f}mm" if s.pad_slip is not None else f" {'-':>9}"
        print(f"{s.step:>4}{mark} {u[0]*1e3:>8.4f},{u[1]*1e3:>8.4f} {lo[0]*1e3:>8.4f},{lo[1]*1e3:>8.4f} "
              f"{deviation_text(s):>10} {s.lower_yaw_deg:>8.4f}° {engineering(s.normal_force, 'N'):>12} "
              f"{s.max_slip*1e3:>7.4f}mm{pad_text} {s.newton_iterations:>6} {s.contact_iterations:>7}")


def print_rest(summary) -> None:
    """Which pose is which: the last load step's (loaded, gripper holding) and the rest pose."""
    rest = summary.rest
    if rest is None:
        return
    lo = rest.lower_centroid
    print(f"{'at rest' if rest.settled else 'NOT settled'} after the {rest.mode} release (step {rest.step}, R = release steps): lower face ({lo[0]*1e3:.4f}, {lo[1]*1e3:.4f}) mm, "
          f"yaw {rest.lower_yaw_deg:.4f}°, normal force {rest.normal_force:.4g} N, "
          f"strain energy {rest.strain_energy:.3g} J (the steps before the release are the loaded poses)"
          + (f"; the pad had slid {rest.pad_slip * 1e3:.4g} mm over the upper face when it let go"
             if rest.pad_slip is not None else ""))


def exit_status(run) -> int:
    """0 for a completed run (whose block, if released, settled); otherwise the
    failure on stderr and :data:`EXIT_SOLVER_FAILURE`."""
    if not run.completed:  # an unsettled release is a failed run too (pushplan.run.driver)
        print(f"pushplan: solver failure: {run.summary.failure.message}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def cmd_simulate(args) -> int:
    from contextlib import ExitStack

    from ..config import load_scenario
    from ..config.budget import check_memory
    from ..config.commands import read_command_file
    from ..config.fingerprint import check_plan_scenario
    from ..outputs.transaction import output_file_lock, output_transaction
    from ..run import simulate
    from ..run.simulate import RECORDING_FILE

    scenario = load_scenario(args.scenario)
    commands = None
    if args.commands is not None:
        commands, document = read_command_file(args.commands)
        check_plan_scenario(document, scenario.to_dict(), args.commands, force=args.force)
    if not (scenario.commands if commands is None else commands):
        raise InputError(f"nothing to simulate: no load steps in {args.commands or args.scenario}")
    check_memory(scenario.elements, scenario.quadrature, override=args.no_memory_check)
    model = scenario.model()  # mesh and material checks before anything is written
    observers = []
    if args.observations:
        from ..config.observations import observation_format
        from ..run.observations import ObservationsFile

        observation_format(args.observations)
        obs_lock = output_file_lock(args.observations, "--observations")
        observers.append(ObservationsFile(obs_lock.out))
    out = output_transaction(args.out, RUN_FILES)
    fclib = output_transaction(args.export_fclib, FCLIB_FILES, what="--export-fclib") if args.export_fclib else None
    with ExitStack() as stack:
        if args.observations:
            stack.enter_context(obs_lock)
        stack.enter_context(out)
        if fclib is not None:
            stack.enter_context(fclib)
        run = simulate(scenario, out.path, commands=commands, model=model, progress=not args.quiet,
                       recording=not args.no_recording, export_fclib=fclib.path if fclib else None,
                       observers=observers)
    for warning in run.summary.warnings:  # --quiet keeps warnings
        print(f"pushplan: warning: {warning}", file=sys.stderr)
    if not args.quiet:
        print_steps(run.summary.steps)
        print_rest(run.summary)
        written = [out.out / "summary.json", out.out / "fields.npz"]
        written += [out.out / RECORDING_FILE] if not args.no_recording else []
        written += [args.observations] if args.observations else []
        print(f"wrote {', '.join(map(str, written[:-1]))} and {written[-1]} ({run.summary.elapsed_s:.2f} s)")
    return exit_status(run)


def register(subparsers) -> None:
    p = subparsers.add_parser("simulate", help="run a scenario's load steps through the FE model")
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder (summary.json, fields.npz)")
    p.add_argument("--commands", help="plan.json whose upper-face commands replace the scenario's [[load]]")
    p.add_argument("--observations", metavar="FILE",
                   help="also write the run as an observation file (.csv or .json: commands, lower-face pose, "
                   "the force the gripper applies on the block, what a wrist sensor reads; see docs/conventions.md)")
    p.add_argument("--force", action="store_true",
                   help="run the --commands of a plan made for another scenario (block, material, friction, [plan])")
    p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--export-fclib", metavar="DIR",
                   help="write each step's last local contact problem to DIR/step_NNN.hdf5 (FCLIB)")
    add_memory_flag(p)
    p.set_defaults(func=cmd_simulate)
