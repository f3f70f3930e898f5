"""``pushplan sweep SWEEP --out DIR``: run a scenario over parameter grids (local
process pool or Dask) and tabulate the cases."""

from __future__ import annotations

import time

from ..errors import EXIT_SOLVER_FAILURE
from .simulate import add_memory_flag

EXECUTORS = ("process", "dask")
"""``pushplan.config.sweep.EXECUTORS``, repeated so that ``--help`` stays cheap."""


def print_case(done: int, total: int, row: dict) -> None:
    """The progress line of a case that ran."""
    detail = row["error"] or (
        f"lag angle {row['lag_angle_deg']:.3f} deg, deviation {row['direction_deviation_deg']:.3f} deg"
        if row["lag_angle_deg"] is not None and row["direction_deviation_deg"] is not None else "")
    print(f"[{done:>{len(str(total))}}/{total}] {row['case']}: {row['status']}  {detail}", flush=True)


def _check_memory(sweep, args) -> None:
    """The largest case times the cases run at once must fit in the available memory
    (not for a remote scheduler: its memory is not ours)."""
    from ..config.budget import check_memory, estimate_memory

    if args.scheduler is not None or not sweep.cases:
        return

    def mesh(case):
        return [int(v) for v in case.columns["elements"].split("x")], int(case.columns["quadrature"])

    biggest = max(sweep.cases, key=lambda c: estimate_memory(*mesh(c)))
    workers = args.workers if args.workers is not None and args.workers > 0 else sweep.workers
    elements, quadrature = mesh(biggest)
    check_memory(elements, quadrature, copies=max(1, min(workers or 1, len(sweep.cases))),
                 override=args.no_memory_check, what=f"case {biggest.case_id} block.elements")


def cmd_sweep(args) -> int:
    """Exit 0 when every case completed, 3 when one failed or raised (the table lists it)."""
    from ..config.sweep import load_sweep
    from ..studies.sweep_run import run_sweep

    sweep = load_sweep(args.sweep)
    _check_memory(sweep, args)
    started = time.perf_counter()
    result = run_sweep(
        sweep, args.out, executor=args.executor, scheduler=args.scheduler, workers=args.workers,
        figure=args.figure, rerun_failed=args.rerun_failed, progress=None if args.quiet else print_case,
    )
    if not args.quiet:  # the table and the files say it all; --quiet prints warnings and errors only
        _print_totals(result, started)
    return 0 if result.all_completed else EXIT_SOLVER_FAILURE


def _print_totals(result, started: float) -> None:
    counts = {s: sum(r["status"] == s for r in result.rows) for s in ("completed", "failed", "error")}
    print(f"{len(result.rows)} cases ({len(result.ran)} run, {len(result.skipped)} already finished): "
          f"{counts['completed']} completed, {counts['failed']} failed, {counts['error']} errors "
          f"in {time.perf_counter() - started:.1f} s")
    for paths in result.outputs.values():
        for p in paths:
            print(f"wrote {p}")


def register(subparsers) -> None:
    """Add the ``sweep`` subcommand."""
    from ..limits import MAX_WORKERS
    from .args import count

    p = subparsers.add_parser("sweep", help="run a scenario over parameter grids (local process pool or Dask)")
    p.add_argument("sweep", help="sweep TOML file (see pushplan.config.sweep)")
    p.add_argument("--out", required=True, help="output folder (results.csv, cases/, heat map); reruns resume")
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address (implies --executor dask)")
    p.add_argument("--executor", choices=EXECUTORS, help="override the sweep file's executor")
    p.add_argument("--workers", type=count(1, MAX_WORKERS),
                   help="local pool / LocalCluster size (default: the file's, or CPU count)")
    p.add_argument("--figure", help="also write the heat map here, e.g. docs/figures/sweep_twist.png")
    p.add_argument("--rerun-failed", action="store_true", help="also rerun cases that ended in a solver failure")
    p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")
    add_memory_flag(p)
    p.set_defaults(func=cmd_sweep)
