"""``pushplan mujoco {import,compare,cosim,export}``: the MuJoCo bridge commands.

Top-level imports are argparse-level only; ``mujoco``, numpy and the bridge are
imported inside the command functions (``pushplan --help`` stays cheap).
"""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE, InputError


def _scene(args):
    """(MjcfScene, BridgeSettings) of ``args.scene`` with the command-line overrides."""
    from ..config.mujoco import bridge_settings
    from ..mujoco.scene import open_scene

    scene, settings = open_scene(args.scene, block=args.block, floor=args.floor)
    overrides = {k: v for k, v in (("gripper", getattr(args, "gripper", None)),
                                   ("control_period", getattr(args, "control_period", None))) if v is not None}
    if overrides:
        settings = bridge_settings({**settings.to_dict(), **overrides})
    return scene, settings


def _commands(args, scene) -> tuple:
    if getattr(args, "commands", None):
        from ..config.commands import load_commands

        return tuple(load_commands(args.commands))
    if not scene.scenario.commands:
        raise InputError("no commands: give --commands plan.json or a scenario TOML with [[load]] steps")
    return scene.scenario.commands


def _fe_model(args, scene):
    return scene.scenario.model(elements=tuple(args.elements) if args.elements else None,
                                quadrature=args.quadrature, what="--elements" if args.elements else None)


def cmd_import(args) -> int:
    import math

    from fe_contact import GRAVITY

    from .units import engineering

    scene, _ = _scene(args)
    if args.quiet:  # the scene loads and passes every check: nothing to print
        return 0
    s = scene.scenario
    print(f"block {scene.block_body!r} ({scene.block_geom}): size {[round(v * 1e3, 6) for v in s.size]} mm, "
          f"mass {scene.block_mass * 1e3:.4g} g")
    c = scene.lower_centre * 1e3
    print(f"rest pose (world, the FE frame's origin): lower-face centre {c[0]:.6g}, {c[1]:.6g}, {c[2]:.6g} mm, "
          f"yaw {math.degrees(scene.yaw):.6g} deg")
    print(f"friction ({scene.pair or 'dynamic contact'}): mu_x = {s.mu_x}, mu_y = {s.mu_y}, angle = {s.angle_deg} deg")
    print(f"material: E = {s.young:.4g} Pa, nu = {s.poisson}, density = {s.density:.6g} kg/m^3 "
          f"(FE self-weight rho g V = {engineering(s.density * GRAVITY * math.prod(s.size), 'N')})")
    for k, v in scene.from_mjcf.items():
        print(f"  from MJCF: {k} <- {v}")
    for k, v in scene.not_from_mjcf.items():
        print(f"  not from MJCF: {k} <- {v}")
    for note in scene.notes:
        print(f"  note: {note}")
    return 0


def cmd_compare(args) -> int:
    import math

    from ..mujoco.compare import MODEL_NOTES, PAIR_AXES_LIMITATION, compare
    from ..outputs.transaction import output_transaction

    scene, settings = _scene(args)
    commands = _commands(args, scene)
    models = [name for name in MODEL_NOTES if not (args.no_flex and name == "flex_isotropic")]
    fe_model = _fe_model(args, scene)
    tx = output_transaction(args.out, ("comparison.json", "comparison.png"))
    with tx:
        result = compare(scene, commands, settings, fe_model, models, tx.path)
    out = tx.out
    if args.quiet:
        return 0
    print("world frame: lower = lower-face centre displacement, yaw = its yaw change")
    print(f"{'model':>15} {'lower x,y (mm)':>20} {'yaw':>9} {'twist':>9} {'deviation':>10} {'wall':>7}")
    for name, run in result.models.items():
        last = run.steps[-1]
        lo = last.lower * 1e3
        print(f"{name:>15} {lo[0]:>9.4f},{lo[1]:>9.4f} {math.degrees(last.lower_yaw):>8.3f}° "
              f"{math.degrees(last.twist):>8.3f}° {math.degrees(last.deviation):>9.3f}° {run.wall_s:>6.2f}s")
    print(f"note: {PAIR_AXES_LIMITATION}")
    print(f"wrote {out / 'comparison.json'} and {out / 'comparison.png'}")
    return 0


def cmd_cosim(args) -> int:
    from ..mujoco.cosim import run_cosimulation
    from ..outputs.atomic import atomic_write_json
    from ..outputs.transaction import output_transaction
    from ..run.summary import RunStatus

    scene, settings = _scene(args)
    commands = _commands(args, scene)
    fe_model = _fe_model(args, scene)
    tx = output_transaction(args.out, ("cosim.json", "cosim.rrd"))
    with tx:
        record = run_cosimulation(scene, commands, settings.gripper, settings.control_period, fe_model,
                                  rrd_path=None if args.no_rerun else tx.path / "cosim.rrd")
        atomic_write_json(tx.path / "cosim.json", record.to_dict())
    _print_cosim(args, scene, record, tx.out)
    if record.status is not RunStatus.COMPLETED:
        print(f"pushplan: solver failure at period {len(record.periods)}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def _print_cosim(args, scene, record, out) -> None:
    """The period table and the rate (nothing with ``--quiet``)."""
    import math

    import numpy as np

    from ..run.summary import StepSummary
    from .units import deviation_text, engineering

    if args.quiet:
        return
    print("world frame: lower = lower-face centre displacement, yaw = its yaw change, "
          "F = gripper force on the block (N)")
    for p in record.periods:
        rep = p.report
        lo = (np.asarray(p.lower_centre) - scene.lower_centre) * 1e3
        f = np.where(np.abs(p.gripper_force) > 1e-9 * np.linalg.norm(p.gripper_force), p.gripper_force, 0.0)
        force = ", ".join(engineering(float(v), "N") for v in f)  # rounding-level components shown as 0
        deviation = deviation_text(StepSummary.from_report(rep)) if rep.converged else "-"
        print(f"period {p.period:>3} t = {p.time:.3f} s  lower {lo[0]:8.4f},{lo[1]:8.4f} mm  "
              f"yaw {math.degrees(p.lower_yaw - scene.yaw):7.3f}°  lower dev. {deviation:>8}  "
              f"F {force}  FE {rep.wall_time * 1e3:6.1f} ms")
    print(f"co-simulation rate: {record.rate_periods_per_s:.2f} control periods/s "
          f"({len(record.periods)} periods, {record.steps_per_period} MuJoCo steps each, "
          f"{record.wall_s:.2f} s; start-up {record.startup_s:.2f} s loading the compiled kernels)")
    print(f"wrote {out / 'cosim.json'}" + ("" if args.no_rerun else f" and {out / 'cosim.rrd'}"))


def _export_path(args):
    """``--out`` with the ``--format`` suffix; a different suffix is bad input."""
    from pathlib import Path

    out = Path(args.out)
    if args.format is None:
        return out
    if out.suffix.lower() == f".{args.format}":
        return out
    if out.suffix:
        raise InputError(f"--format {args.format} does not match --out {out.name}")
    return out.with_suffix(f".{args.format}")


def cmd_export(args) -> int:
    from ..mujoco.trajectory import export_plan
    from ..outputs.transaction import output_file_lock

    out = _export_path(args)
    lock = output_file_lock(out, "--out")
    scene, settings = _scene(args)
    commands = _commands(args, scene)
    fe_model = _fe_model(args, scene)
    with lock:
        path = export_plan(out, scene, commands, settings.gripper, settings.control_period, fe_model)
    if not args.quiet:
            print(f"wrote {path} ({len(commands) + 1} knots of gripper and FE block pose, {settings.control_period} s apart)")
    return 0


def _common(q, commands=True, fe=True) -> None:
    from ..limits import MAX_CONTROL_PERIOD, MAX_ELEMENTS_PER_AXIS
    from .args import count, real

    q.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")
    q.add_argument("scene", help="scenario TOML with a [mujoco] table, or an MJCF .xml")
    q.add_argument("--block", help="block body or box geom (default from [mujoco] or 'block')")
    q.add_argument("--floor", help="floor plane geom (default from [mujoco] or 'floor')")
    if commands:
        q.add_argument("--gripper", help="gripper mocap body (default from [mujoco] or 'gripper')")
        q.add_argument("--commands", help="plan.json whose commands replace the scenario's [[load]]")
        q.add_argument("--control-period", type=real(0.0, MAX_CONTROL_PERIOD),
                       help=f"s of MuJoCo time per command (at most {MAX_CONTROL_PERIOD})")
    if fe:
        q.add_argument("--elements", type=count(1, MAX_ELEMENTS_PER_AXIS), nargs=3, metavar=("NX", "NY", "NZ"),
                       help="FE mesh override")
        q.add_argument("--quadrature", type=int, choices=(2, 3), help="Gauss points per direction override")


def register(subparsers) -> None:
    """Add ``pushplan mujoco {import,compare,cosim,export}``."""
    p = subparsers.add_parser("mujoco", help="MuJoCo bridge: MJCF import, rigid/flex comparison, "
                                             "co-simulation, plan export")
    sub = p.add_subparsers(dest="mujoco_command", metavar="ACTION")
    sub.required = True
    q = sub.add_parser("import", help="show what the MJCF scene gives the FE model")
    _common(q, commands=False, fe=False)
    q.set_defaults(func=cmd_import)
    q = sub.add_parser("compare", help="FE vs MuJoCo rigid (weld, force) vs flex (isotropic) on the same commands")
    _common(q)
    q.add_argument("--out", required=True, help="output folder (comparison.json, comparison.png)")
    q.add_argument("--no-flex", action="store_true", help="skip the flex model")
    q.set_defaults(func=cmd_compare)
    q = sub.add_parser("cosim", help="headless co-simulation: gripper follows the commands, FE block in MuJoCo")
    _common(q)
    q.add_argument("--out", required=True, help="output folder (cosim.json, cosim.rrd)")
    q.add_argument("--no-rerun", action="store_true", help="do not write the rerun recording")
    q.set_defaults(func=cmd_cosim)
    q = sub.add_parser("export", help="write a plan as MuJoCo keyframes (.xml) or times and poses (.npz, .csv): "
                                      "gripper mocap and FE block pose")
    _common(q)
    q.add_argument("--out", required=True, help="output file, .xml (MJCF <keyframe>), .npz or .csv")
    q.add_argument("--format", choices=("xml", "npz", "csv"),
                   help="file format (default: the --out suffix; a suffix is added when missing)")
    q.set_defaults(func=cmd_export)
