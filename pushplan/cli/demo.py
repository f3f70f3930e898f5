"""``pushplan demo --out DIR``: the main job, the paper reproduction then a planning demo."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def cmd_demo(args) -> int:
    from . import main
    from ..outputs.transaction import OutputLock, check_output_path
    from ..resources import scenario_path

    out = Path(args.out)
    quiet = ["--quiet"] if args.quiet else []
    jobs = [
        ["paper", "--out", str(out / "paper"), *quiet],
        ["plan", str(scenario_path("plan_steel_case3.toml")), "--out", str(out / "plan_steel_case3"), *quiet],
    ]
    status = 0
    lock = OutputLock(check_output_path(out))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {out}: {exc.strerror}") from None
    with lock:  # a second demo into --out refuses at once
        for argv in jobs:
            if not args.quiet:
                print(f"== pushplan {' '.join(argv)}", flush=True)
            status = max(status, main(argv))
    if not args.quiet:
        print(f"outputs in {out}/: paper/report.md, paper/figures/, plan_steel_case3/plan.json, */recording.rrd")
    return status


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="main job: the paper reproduction and a planning demo")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--quiet", action="store_true", help="no progress lines (each step's own --quiet)")
    p.set_defaults(func=cmd_demo)
