"""``pushplan demo --out DIR``: the main job, the paper reproduction then a planning demo."""

from __future__ import annotations

from pathlib import Path


def cmd_demo(args) -> int:
    from . import main
    from ..resources import scenario_path

    out = Path(args.out)
    jobs = [
        ["paper", "--out", str(out / "paper")],
        ["plan", str(scenario_path("plan_steel_case3.toml")), "--out", str(out / "plan_steel_case3")],
    ]
    status = 0
    for argv in jobs:
        print(f"== pushplan {' '.join(argv)}", flush=True)
        status = max(status, main(argv))
    print(f"outputs in {out}/: paper/report.md, paper/figures/, plan_steel_case3/plan.json, */recording.rrd")
    return status


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="main job: the paper reproduction and a planning demo")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.set_defaults(func=cmd_demo)
