"""``pushplan replay FILE --out DIR``: re-execute the commands of a plan.json or a
recording and compare the lower-face trajectory; ``pushplan view FILE``: open a
recording in the rerun viewer."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from ..errors import EXIT_UNAVAILABLE, InputError
from .simulate import add_memory_flag

RECORDING_FILE = "recording.rrd"
COLOUR_FIELDS = ("slip", "slip_path", "pressure")  # pushplan.outputs.recording.FIELDS


def lower_face_deviation(reference, other):
    """Per-step distance (m) between two lower-face centroid trajectories (n, 3),
    over their common length."""
    import numpy as np

    n = min(len(reference), len(other))
    return np.linalg.norm(np.asarray(reference, float)[:n] - np.asarray(other, float)[:n], axis=1)


def _source(path: Path):
    """(commands, original recording or None, plan document or None) of a plan .json or an .rrd."""
    from ..config.commands import read_command_file
    from ..outputs.recording_read import read_recording

    if path.suffix == ".rrd":
        original = read_recording(path)
        return list(original.commands), original, None
    if path.suffix == ".json":
        sibling = path.parent / RECORDING_FILE
        commands, document = read_command_file(path)
        return list(commands), read_recording(sibling) if sibling.is_file() else None, document
    raise InputError(f"replay needs a plan .json or a .rrd recording, got {path}")


def cmd_replay(args) -> int:
    from ..config import load_scenario, parse_scenario
    from ..config.budget import check_memory
    from ..config.fingerprint import check_plan_scenario
    from ..outputs import atomic_write_json
    from ..outputs.transaction import output_transaction
    from ..outputs.recording import Recorder
    from ..run import simulate
    from ..run.observers import RecordingFile
    from ..run.simulate import resolved_scenario
    from .simulate import RUN_FILES, exit_status

    source = Path(args.file)
    commands, original, document = _source(source)
    if not commands:
        raise InputError(f"{source} holds no commands")
    if args.scenario is not None:
        scenario = load_scenario(args.scenario)
        if document is not None:
            check_plan_scenario(document, scenario.to_dict(), source, force=args.force)
    elif original is not None and original.scenario is not None:
        scenario = parse_scenario(original.scenario, name=original.run_name)
    else:
        raise InputError(f"no scenario stored with {source}: pass --scenario")
    check_memory(scenario.elements, scenario.quadrature, override=args.no_memory_check)
    model = scenario.model()
    tx = output_transaction(args.out, (*RUN_FILES, "replay.json"))
    with tx:
        recorder = Recorder(tx.path / RECORDING_FILE, f"{scenario.name}-replay", model.mesh, field=args.field,
                            scenario=resolved_scenario(scenario, commands))
        run = simulate(scenario, tx.path, commands=commands, model=model, recording=False,
                       progress=not args.quiet, observers=[RecordingFile(recorder)])
        report = _compare(source, scenario, commands, run, original, tx.out)
        atomic_write_json(tx.path / "replay.json", report)
    return exit_status(run)


def _compare(source, scenario, commands, run, original, out) -> dict:
    """Print the replay and its deviation from the original trajectory; replay.json's content."""
    import numpy as np

    replayed = np.array([s.lower_centroid for s in run.summary.steps], float).reshape(-1, 3)
    report = {"source": str(source), "scenario": scenario.name, "steps_replayed": len(replayed),
              "reference": None, "max_deviation_m": None, "deviation_m": None}
    print(f"replayed {len(replayed)} of {len(commands)} steps of {source} with scenario {scenario.name} "
          f"(mu_x = {scenario.mu_x}, mu_y = {scenario.mu_y}); wrote {out / RECORDING_FILE}")
    if original is not None and len(original.lower_centroid):
        dev = lower_face_deviation(original.lower_centroid, replayed)
        report.update(reference=original.run_name, max_deviation_m=float(dev.max()), deviation_m=dev)
        k = int(dev.argmax())
        print(f"max lower-face deviation from {original.run_name}: {dev.max():.6e} m "
              f"({dev.max() * 1e6:.4f} um, at compared step {k + 1}; {len(dev)} steps compared)")
    else:
        print("no original trajectory to compare with (no recording.rrd next to the plan)")
    return report


def cmd_view(args) -> int:
    path = Path(args.file)
    if not path.is_file():
        raise InputError(f"recording not found: {path}")
    exe = shutil.which("rerun") or shutil.which("rerun", path=str(Path(sys.executable).parent))
    has_display = sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or
                                                               os.environ.get("WAYLAND_DISPLAY"))
    if exe and has_display:
        import subprocess

        subprocess.Popen([exe, str(path)], start_new_session=True)
        if not args.quiet:
            print(f"opened {path} in the rerun viewer")
        return 0
    reason = "no display" if exe else "no rerun viewer on PATH"
    print(f"pushplan: {reason}: open the recording with `rerun {path}` on a machine with a display "
          f"(pip install rerun-sdk), or drag it onto https://rerun.io/viewer", file=sys.stderr)
    return EXIT_UNAVAILABLE


def register(subparsers) -> None:
    p = subparsers.add_parser("replay", help="re-execute the commands of a plan.json or recording.rrd")
    p.add_argument("file", help="plan .json (its folder's recording.rrd is the reference) or .rrd")
    p.add_argument("--scenario", help="scenario TOML to replay with (default: the one stored in the recording)")
    p.add_argument("--out", required=True, help="output folder (summary.json, fields.npz, recording.rrd, replay.json)")
    p.add_argument("--force", action="store_true", help="replay a plan made for a scenario other than --scenario")
    p.add_argument("--field", default="slip", choices=COLOUR_FIELDS, help="block colour field")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_memory_flag(p)
    p.set_defaults(func=cmd_replay)
    p = subparsers.add_parser("view", help="open a recording in the rerun viewer")
    p.add_argument("file", help=".rrd recording")
    p.add_argument("--quiet", action="store_true", help="no line when the viewer opens")
    p.set_defaults(func=cmd_view)
