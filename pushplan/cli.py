"""Command-line interface: ``pushplan <command> ...``.

Exit status: 0 success, 2 bad input (one-line message, nothing written),
3 solver failure (message, ``summary.json`` keeps the finished steps).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_SOLVER_FAILURE = 3
SCENARIO_DIR = Path(__file__).resolve().parents[1] / "scenarios"
COMMAND_MODULES: list[str] = ["pushplan.paper", "pushplan.recording", "pushplan.mujoco_bridge", "pushplan.sweep", "pushplan.planner"]  # see build_parser


class CliError(Exception):
    """Bad input detected by a command: printed as one line, exit status 2."""


def _print_steps(summary: dict) -> None:
    print(f"{'step':>4} {'upper x,y (mm)':>18} {'lower x,y (mm)':>18} {'twist':>8} {'yaw':>8} "
          f"{'N (kN)':>9} {'max slip':>9} {'newton':>6} {'contact':>7}")
    for s in summary["steps"]:
        u, lo = s["upper_centroid"], s["lower_centroid"]
        print(f"{s['step']:>4} {u[0]*1e3:>8.4f},{u[1]*1e3:>8.4f} {lo[0]*1e3:>8.4f},{lo[1]*1e3:>8.4f} "
              f"{s['twist_deg']:>7.3f}° {s['lower_yaw_deg']:>7.4f}° {s['normal_force']/1e3:>9.2f} "
              f"{s['max_slip']*1e3:>7.4f}mm {s['newton_iterations']:>6} {s['contact_iterations']:>7}")


def cmd_simulate(args) -> int:
    from .io import prepare_output_dir
    from .scenario import load_scenario
    from .simulate import simulate

    scenario = load_scenario(args.scenario)
    commands = None
    if args.commands is not None:
        from .plan_io import load_commands

        commands = load_commands(args.commands)
    if not (scenario.commands if commands is None else commands):
        raise CliError(f"nothing to simulate: no load steps in {args.commands or args.scenario}")
    model = scenario.model()  # mesh and material checks before anything is written
    out = prepare_output_dir(args.out)
    fclib_dir = prepare_output_dir(args.export_fclib) if args.export_fclib else None
    result = simulate(scenario, out, commands=commands, model=model, progress=not args.quiet,
                      recording=not args.no_recording, export_fclib=fclib_dir)
    _print_steps(result.summary)
    print(f"wrote {out / 'summary.json'} and {out / 'fields.npz'} ({result.summary['elapsed_s']:.2f} s)")
    return simulation_exit_status(result)


def simulation_exit_status(result) -> int:
    """0 for a completed :class:`~pushplan.simulate.SimulationResult`; otherwise print
    the failure on stderr and return :data:`EXIT_SOLVER_FAILURE`."""
    if not result.completed:
        print(f"pushplan: solver failure: {result.summary['failure']['message']}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def cmd_demo(args) -> int:
    """The main job: the paper reproduction, then a planning demo, into ``args.out``."""
    out = Path(args.out)
    jobs = [
        ["paper", "--out", str(out / "paper")],
        ["plan", str(SCENARIO_DIR / "plan_steel_case3.toml"), "--out", str(out / "plan_steel_case3")],
    ]
    status = 0
    for argv in jobs:
        print(f"== pushplan {' '.join(argv)}", flush=True)
        status = max(status, main(argv))
    print(f"outputs in {out}/: paper/report.md, paper/figures/, plan_steel_case3/plan.json, */recording.rrd")
    return status


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pushplan",
        description="Pushing deformable blocks over anisotropic-friction surfaces "
        "(FE model of Feng, Hjiaj, de Saxce, Mroz 2006).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("simulate", help="run a scenario's load steps through the FE model")
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder (summary.json, fields.npz)")
    p.add_argument("--commands", help="plan.json whose upper-face commands replace the scenario's [[load]]")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-recording", action="store_true", help="do not write recording.rrd")
    p.add_argument("--export-fclib", metavar="DIR",
                   help="write each step's last local contact problem to DIR/step_NNN.hdf5 (FCLIB)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("demo", help="main job: the paper reproduction and a planning demo")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.set_defaults(func=cmd_demo)

    # Further subcommands live next to their code: each module has
    # ``register(subparsers)`` adding its parser with ``set_defaults(func=...)``,
    # and imports heavy dependencies (casadi, mujoco, rerun) inside ``func`` only.
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (CliError, ValueError) as exc:  # ScenarioError is a ValueError
        message = " ".join(str(exc).split())  # one line, whatever the exception text
        print(f"pushplan: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
