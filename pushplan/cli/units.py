"""Numbers as a person reads them on the terminal: SI units with engineering prefixes,
and angles only where they mean something."""

from __future__ import annotations

import math

_PREFIXES = {-12: "p", -9: "n", -6: "u", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}
TWIST_MIN_MOTION = 0.01
"""Lower-face travel, as a fraction of the upper face's, below which the block sticks and
the twist (the angle between the two travels) is the direction of a rounding error."""


def engineering(value: float, unit: str, digits: int = 4) -> str:
    """``value`` with an engineering prefix: ``engineering(60.2, "N") == "60.2 N"``,
    ``engineering(9.09e5, "N") == "909 kN"``."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g} {unit}"
    exponent = min(max(3 * math.floor(math.log10(abs(value)) / 3), -12), 12)
    return f"{value / 10**exponent:.{digits}g} {_PREFIXES[exponent]}{unit}"


def twist_text(step) -> str:
    """The twist of a :class:`~pushplan.run.StepSummary` in degrees, or ``-`` while the
    lower face has not moved (by less than :data:`TWIST_MIN_MOTION` of the upper face)."""
    upper = math.hypot(*step.upper_centroid[:2])
    lower = math.hypot(*step.lower_centroid[:2])
    if upper == 0 or lower < TWIST_MIN_MOTION * upper:
        return "-"
    return f"{step.twist_deg:.3f}°"
