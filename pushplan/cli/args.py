"""Checked command-line values: argparse ``type=`` functions that accept only finite
numbers in a stated range and counts up to a stated maximum, so that a bad option is
argparse's one-line usage error (exit 2) naming the option, before any work.

    p.add_argument("--ratio", type=real(lo=1.0, hi=100.0), default=2.0)
    p.add_argument("--levels", type=count(3, 12), required=True)
"""

from __future__ import annotations

import argparse
import math


def real(lo: float | None = None, hi: float | None = None, *, closed_lo: bool = False):
    """A finite float with ``lo < v <= hi`` (``lo <= v`` when ``closed_lo``); the
    bounds are stated in the message."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        below = lo is not None and (v < lo if closed_lo else v <= lo)
        if below or (hi is not None and v > hi):
            left = "" if lo is None else f"{lo} {'<=' if closed_lo else '<'} "
            right = "" if hi is None else f" <= {hi}"
            raise argparse.ArgumentTypeError(f"must be {left}value{right}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def count(minimum: int, maximum: int):
    """An integer ``minimum <= n <= maximum`` (digits only, at most 12: no int-string bomb)."""

    def parse(text: str) -> int:
        t = text.strip()
        if not (t.lstrip("+-").isdigit() and len(t) <= 12):
            raise argparse.ArgumentTypeError(f"must be an integer from {minimum} to {maximum}, got {text[:40]!r}")
        n = int(t)
        if not minimum <= n <= maximum:
            raise argparse.ArgumentTypeError(f"must be an integer from {minimum} to {maximum}, got {n}")
        return n

    parse.__name__ = "count"
    return parse


class OneLineParser(argparse.ArgumentParser):
    """Usage errors as one ``pushplan: error:`` line naming the command (exit 2)."""

    def error(self, message: str):
        text = " ".join(str(message).split())
        self.exit(2, f"pushplan: error: {self.prog}: {text} (see {self.prog} --help)\n")
