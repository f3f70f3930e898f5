"""``pushplan paper --out DIR``: reproduce sect. 9 of the paper (figures 6-10, report, VTU)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import EXIT_SOLVER_FAILURE
from .simulate import add_memory_flag

LOCAL_METHODS = ("uzawa", "newton", "uzawa_jacobi")
"""``fe_contact.stepping.model.LOCAL_METHODS``, repeated so that ``--help`` does not import fe_contact."""


PAPER_FILES = ("paper_case*", "figures", "report.json", "report.md")
"""What ``paper`` writes in ``--out`` (``pushplan.studies.paper_run``)."""
PAPER_ELEMENTS = (20, 20, 5)
"""The paper's mesh (``pushplan.studies.paper_cases``), for the memory check."""


def print_report(report, out) -> None:
    """One line per case, the claims (and the checks whose criterion is not met, each as
    "quantity: measured value, criterion ..."), the report path."""
    for case in report.cases:
        if case.steps:
            s = case.steps[-1]
            print(f"{case.name}: {case.run.summary.status.value}, {case.run.summary.elapsed_s:.1f} s, "
                  f"max slip {s.summary.max_slip * 1e3:.4f} mm, lower-face direction deviation (the paper's twist) "
                  f"{round(s.summary.twist_deg, 3) + 0.0:.3f}°, "
                  f"lower-face direction {s.lower_direction_deg:.2f}°")
    for claim in report.claims or ():
        if claim.holds:
            print(f"claim {claim.key}: reproduced")
            continue
        print(f"claim {claim.key}: partly reproduced; finding (a result, not an error; see report.md):")
        for check in claim.failed_checks:
            print(f"    criterion not met: {check.text}")
    print(f"wrote {Path(out) / 'report.md'} ({report.wall_time_s:.1f} s)")


def cmd_paper(args) -> int:
    """Exit 0, or 3 when a case's solver fails (the report keeps the finished steps)."""
    from ..config.budget import check_memory
    from contextlib import nullcontext

    from ..outputs.transaction import OutputLock, check_output_path, output_transaction
    from ..studies.paper_run import run_paper

    check_memory(args.elements or PAPER_ELEMENTS, args.quadrature or 3, override=args.no_memory_check,
                 what="--elements")
    docs = OutputLock(check_output_path(args.docs, "--docs")) if args.docs else nullcontext()
    tx = output_transaction(args.out, PAPER_FILES)
    with docs, tx:  # --docs: a shared folder (docs/figures) written file by file, atomically, locked
        report = run_paper(tx.path, elements=args.elements, quadrature=args.quadrature,
                           local_method=args.local_method, docs_dir=args.docs, progress=not args.quiet)
    if not args.quiet:  # warnings and errors only
        print_report(report, args.out)
    if not report.completed:
        print(f"pushplan: solver failure in {', '.join(report.failed_cases)}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def register(subparsers) -> None:
    """Add the ``paper`` subcommand."""
    from ..limits import MAX_ELEMENTS_PER_AXIS
    from .args import count

    p = subparsers.add_parser("paper", help="reproduce the paper's sect. 9 (figures 6-10, report, VTU)")
    p.add_argument("--out", default="out/paper", help="output folder (default: out/paper)")
    p.add_argument("--elements", nargs=3, type=count(1, MAX_ELEMENTS_PER_AXIS), metavar=("NX", "NY", "NZ"),
                   help="mesh override for coarse runs (default: the paper's 20 20 5)")
    p.add_argument("--quadrature", type=int, choices=(2, 3), help="Gauss points per direction (default: 3)")
    p.add_argument("--local-method", choices=LOCAL_METHODS,
                   help="local contact solver (default: the scenarios'; the paper's is uzawa)")
    p.add_argument("--docs", metavar="DIR",
                   help="also copy the PNGs into DIR (the documentation's figures: --docs docs/figures)")
    p.add_argument("--quiet", action="store_true", help="print nothing but warnings and errors")
    add_memory_flag(p)
    p.set_defaults(func=cmd_paper)
