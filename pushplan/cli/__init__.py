"""Command-line interface: ``pushplan <command> ...``, one thin module per command.

Exit status: 0 success; 2 bad input (:class:`~pushplan.errors.InputError`: one line,
nothing written); 3 solver failure (:class:`~pushplan.errors.SolverFailure` or a run
that stopped: message on stderr, the finished part kept); 4 what the command needs is
not on this machine (``view`` without a display); 1 with one line for an output that
could not be written (:class:`~pushplan.errors.OutputFailure`: full disk, quota; the
previous output left as it was); 130 when interrupted (SIGINT); anything else is a bug
and shows its traceback (exit 1).
"""

from __future__ import annotations

import argparse
import atexit
import gc
import importlib
import os
import sys
import warnings

from ..errors import (EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_OUTPUT_FAILURE, EXIT_SOLVER_FAILURE, InputError,
                      InputWarning, OutputFailure, SolverFailure)

# each module has ``register(subparsers)`` and imports its heavy dependencies
# (numpy, fe_contact, casadi, mujoco, rerun) inside the command function only
COMMAND_MODULES = ("simulate", "demo", "paper", "plan", "replay", "mujoco", "sweep", "convergence", "identify", "closed_loop",
                   "serve")

__all__ = ["EXIT_BAD_INPUT", "EXIT_SOLVER_FAILURE", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from .args import OneLineParser

    parser = OneLineParser(
        prog="pushplan",
        description="Pushing deformable blocks over anisotropic-friction surfaces "
        "(FE model of Feng, Hjiaj, de Saxce, Mroz 2006).",
    )
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


class _VersionAction(argparse.Action):
    """``--version``: argparse's own action, with the version looked up only when asked
    (``importlib.metadata`` costs 20-40 ms of every command's start-up)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, help="show program's version number and exit"):
        super().__init__(option_strings, dest, default=argparse.SUPPRESS, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(f"pushplan {_version()}\n", sys.stdout)
        parser.exit()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pushplan")
    except PackageNotFoundError:  # a source tree that was never installed
        return "unknown (not installed)"


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Input warnings (:class:`~pushplan.errors.InputWarning`) as one line on stderr."""
    print(f"pushplan: warning: {_one_line(message)}", file=sys.stderr)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _leave_objects_to_the_os() -> None:
    """At interpreter exit (an ``atexit`` handler, so after the command and before the
    interpreter's finalisation): freeze the objects alive then out of the garbage
    collector (``gc.freeze``), so the shutdown's full collection does not traverse every
    one of them (numpy, scipy, the model): 0.23-0.43 s after a ``simulate`` of the paper
    case, 0.05-0.07 s with it (loaded 2-core machine, with numba then imported too).  Objects are still released
    by reference counting and the interpreter still flushes the standard streams; only
    garbage in reference cycles is left to the OS, as the process ends.  In a process that
    goes on after ``main`` (tests) it runs once, at that process's exit."""
    gc.freeze()


def main(argv=None) -> int:
    """Run a command; warnings raised on the way are shown after it, except before a
    clean one-line outcome (exit 2, 3, 1 for a full disk, 130), which they would bury.

    The held-back warnings are shown after ``catch_warnings`` has been left: shown
    inside it, each would be recorded again and the loop over them would never end."""
    atexit.unregister(_leave_objects_to_the_os)  # registered once however often main runs
    atexit.register(_leave_objects_to_the_os)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error (one line, exit 2)
        return exc.code
    status = None
    caught: list = []
    if getattr(args, "no_memory_check", False):  # for every model of the run, workers included
        from ..config.budget import OVERRIDE_ENV

        os.environ[OVERRIDE_ENV] = "1"
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", InputWarning)
            status = _run(args)
    finally:
        _show_held(caught, status)
        if getattr(args, "no_memory_check", False):
            os.environ.pop(OVERRIDE_ENV, None)
    return status


def _show_held(caught: list, status) -> None:
    """Show each held-back warning once: none before bad input's one line (exit 2),
    input warnings before any other outcome, others after a success (or a bug's
    traceback)."""
    if status == EXIT_BAD_INPUT:
        return
    for w in caught:
        if issubclass(w.category, InputWarning):
            _show_warning(w.message, w.category, w.filename, w.lineno)
        elif status in (None, 0):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def _run(args) -> int:
    try:
        return args.func(args)
    except InputError as exc:
        print(f"pushplan: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SolverFailure as exc:
        print(f"pushplan: solver failure: {_one_line(exc)}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    except OSError as exc:
        from ..outputs.transaction import output_failure

        failure = exc if isinstance(exc, OutputFailure) else output_failure(exc, exc.filename or "the output")
        if failure is None:
            raise
        print(f"pushplan: error: {_one_line(failure)}", file=sys.stderr)
        return EXIT_OUTPUT_FAILURE
    except KeyboardInterrupt:
        resume = ", rerun to resume" if args.command in ("sweep", "convergence") else ""
        print(f"pushplan: interrupted{resume}", file=sys.stderr)
        return EXIT_INTERRUPTED
