"""The outcomes a user is told about without a traceback, and their exit statuses.

``InputError``   bad input (a file, a key, a value): one line naming it, exit 2,
                 nothing written.
``SolverFailure`` the model or the planner did not converge: exit 3, the finished
                 part of the run is kept.
``OutputFailure`` the output could not be written (full disk, quota, read-only file
                 system): one line, exit 1, the previous output left as it was.
Interrupted (SIGINT): exit 130; the output folder is left as it was.
``InputWarning``  valid input that is probably in the wrong unit: one warning line, the
                 run goes on.  ``view`` without a display or viewer: exit 4.

Anything else raised inside ``pushplan`` is a bug: the CLI lets it through with its
traceback (exit 1).  ``InputError`` is a ``ValueError`` so that library callers can
catch bad input the usual way; the CLI catches ``InputError`` only, never a bare
``ValueError``.
"""

from __future__ import annotations

EXIT_BAD_INPUT = 2
EXIT_SOLVER_FAILURE = 3
EXIT_UNAVAILABLE = 4
"""What the command needs is not on this machine (``view`` without a display or viewer)."""
EXIT_OUTPUT_FAILURE = 1
EXIT_INTERRUPTED = 130


class InputError(ValueError):
    """Bad input; the message names the file, key or value (one line)."""


class SolverFailure(RuntimeError):
    """A solver or planner did not reach its tolerance; the message says which and why."""


class InputWarning(UserWarning):
    """Input that is valid but probably not what was meant (a modulus in MPa given as Pa);
    the CLI prints it as one ``pushplan: warning:`` line and goes on."""


class OutputFailure(OSError):
    """The output could not be written (full disk, quota, read-only file system)."""
