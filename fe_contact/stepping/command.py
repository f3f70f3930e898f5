"""The command of one load step (:class:`Command`): the upper face's rigid motion
increment (SI units, radians)."""

from __future__ import annotations

import math
from dataclasses import dataclass


def _finite(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class Command:
    """One load step: rigid motion increment of the upper face.

    Parameters
    ----------
    dx, dy, dz : float
        Translation increment of the upper face, m (world frame).
    dtheta : float
        Rotation increment about the vertical axis through the current upper-face
        centre, rad, counter-clockwise seen from +z.
    """

    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    dtheta: float = 0.0

    def __post_init__(self):
        for name in ("dx", "dy", "dz", "dtheta"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))

    @property
    def moves(self) -> bool:
        """The command moves the gripper."""
        return any((self.dx, self.dy, self.dz, self.dtheta))
