"""``pushplan convergence SCENARIO --levels N --out DIR``: a mesh-convergence study
with Richardson extrapolation and the grid convergence index."""

from __future__ import annotations

import math
from itertools import pairwise
import sys

from ..errors import EXIT_SOLVER_FAILURE, InputError
from .simulate import add_memory_flag


def _check(args, scenario) -> None:
    from ..config.budget import check_memory
    from ..config.scenario import MAX_ELEMENTS
    from ..studies.convergence import level_elements

    if args.levels < 3:
        raise InputError(f"--levels must be >= 3 (three meshes give an order), got {args.levels}")
    if not (math.isfinite(args.ratio) and args.ratio > 1.0):
        raise InputError(f"--ratio must be > 1, got {args.ratio}")
    meshes = [level_elements(scenario.elements, args.ratio, k) for k in range(args.levels)]
    for coarse, fine in pairwise(meshes):
        if math.prod(fine) <= math.prod(coarse):
            raise InputError(f"--levels {args.levels} --ratio {args.ratio}: the meshes {list(coarse)} and "
                             f"{list(fine)} are not refinements of each other (a larger --ratio or coarsest mesh)")
    finest = meshes[-1]
    if math.prod(finest) > MAX_ELEMENTS:
        raise InputError(f"--levels {args.levels} --ratio {args.ratio}: the finest mesh {list(finest)} has more "
                         f"than {MAX_ELEMENTS} elements")
    check_memory(finest, scenario.quadrature, override=args.no_memory_check,
                 what=f"--levels {args.levels} --ratio {args.ratio}: the finest mesh")
    if not scenario.commands:
        raise InputError(f"nothing to simulate: no load steps in {args.scenario}")


def _print(result) -> None:
    print(f"{'quantity':<20} " + " ".join(f"{'x'.join(map(str, lv.elements)):>14}" for lv in result.levels)
          + f" {'extrapolated':>14} {'order':>6} {'GCI':>8}")
    for name, ext in result.extrapolated.items():
        values = [lv.values[name] if lv.values else math.nan for lv in result.levels]
        tail = (f"{ext.value:>14.6g} {ext.order:>6.2f} {100 * ext.gci:>7.3f}%"
                if ext.order is not None and ext.gci is not None else f"  {ext.note}")
        print(f"{name:<20} " + " ".join(f"{v:>14.6g}" for v in values) + " " + tail)


def cmd_convergence(args) -> int:
    from ..config import load_scenario, parse_scenario
    from ..outputs.transaction import output_transaction
    from ..studies.convergence import study, sweep_levels, write

    scenario = load_scenario(args.scenario)
    if args.elements is not None:
        scenario = parse_scenario({**scenario.to_dict(), "block": {**scenario.to_dict()["block"],
                                                                   "elements": args.elements}})
    _check(args, scenario)
    log = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    # the study's files are one transaction; the levels (a resumable sweep, OUT/levels/)
    # are written in place, case by case, under the same lock, and carried over
    tx = output_transaction(args.out, ("convergence.json", "convergence.png"))
    with tx:
        run_levels = None
        if args.workers is not None or args.executor is not None or args.scheduler is not None:
            run_levels = sweep_levels(args.scenario, tx.out, workers=args.workers, executor=args.executor,
                                      scheduler=args.scheduler)
        result = study(scenario, args.levels, args.ratio, run_levels=run_levels, log=log)
        paths = [tx.out / p.name for p in write(result, tx.path)]
    if not args.quiet:  # warnings and errors only
        _print(result)
        print("wrote " + ", ".join(str(p) for p in paths))
    if not result.completed:
        failed = [lv.elements for lv in result.levels if lv.status != "completed"]
        print(f"pushplan: solver failure on the mesh(es) {failed}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def register(subparsers) -> None:
    from ..limits import MAX_ELEMENTS_PER_AXIS, MAX_LEVELS, MAX_RATIO, MAX_WORKERS
    from .args import count, real

    p = subparsers.add_parser("convergence", help="mesh-convergence study: observed order, Richardson "
                              "extrapolation and GCI of the scenario's results")
    p.add_argument("scenario", help="scenario TOML file; its [block] elements are the coarsest mesh")
    p.add_argument("--levels", type=count(3, MAX_LEVELS), required=True,
                   help=f"number of meshes (3 to {MAX_LEVELS})")
    p.add_argument("--ratio", type=real(1.0, MAX_RATIO), default=2.0,
                   help=f"refinement ratio between levels (default 2, at most {MAX_RATIO})")
    p.add_argument("--out", required=True, help="output folder (convergence.json, convergence.png)")
    p.add_argument("--elements", nargs=3, type=count(1, MAX_ELEMENTS_PER_AXIS), metavar=("NX", "NY", "NZ"),
                   help="coarsest mesh (default: the scenario's [block] elements)")
    p.add_argument("--workers", type=count(1, MAX_WORKERS), help="run the levels in parallel on a local pool of this size "
                   "(the sweep machinery; levels land in OUT/levels/)")
    p.add_argument("--executor", choices=("process", "dask"), help="sweep executor for the levels")
    p.add_argument("--scheduler", help="address of a running Dask scheduler for the levels")
    p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")
    add_memory_flag(p)
    p.set_defaults(func=cmd_convergence)
