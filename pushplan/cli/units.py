"""Numbers as a person reads them on the terminal: SI units with engineering prefixes,
and angles only where they mean something."""

from __future__ import annotations

import math

_PREFIXES = {-12: "p", -9: "n", -6: "u", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}


def engineering(value: float, unit: str, digits: int = 4) -> str:
    """``value`` with an engineering prefix: ``engineering(60.2, "N") == "60.2 N"``,
    ``engineering(9.09e5, "N") == "909 kN"``."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g} {unit}"
    exponent = min(max(3 * math.floor(math.log10(abs(value)) / 3), -12), 12)
    return f"{value / 10**exponent:.{digits}g} {_PREFIXES[exponent]}{unit}"


def deviation_text(step) -> str:
    """The lower face's direction deviation of a :class:`~pushplan.run.StepSummary` in
    degrees, or ``-`` where ``summary.json`` has ``null`` (the lower face has not moved:
    :data:`pushplan.run.summary.DIRECTION_MIN_MOTION`)."""
    value = step.lower_direction_deviation_deg
    return "-" if value is None else f"{value:.3f}°"
