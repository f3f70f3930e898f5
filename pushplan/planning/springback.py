"""The reduced model of the release: how much of the elastic lag springs back.

When the gripper lets go, the lower face moves from its loaded pose ``l`` towards
the upper face's ``u`` by a fraction of the lag (positions m, yaw rad):

    rest = l + s (u - l),    s = (s_xy, s_xy, s_yaw),

``s = 1`` for a bonded lift (the block ends stress-free under the upper face), ``s ~ 0``
for a frictional pad much slipperier than the floor.  ``s`` is the least-squares
ratio of the FE rest displacement to the lag over calibration rollouts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NO_LAG = 1e-12
"""Lag (m, or rad for the yaw) below which a rollout says nothing about the spring-back."""


@dataclass(frozen=True)
class Springback:
    """Fractions of the lag that spring back at the release: in-plane and yaw."""

    position: float
    yaw: float

    @property
    def fractions(self) -> np.ndarray:
        """(3,) per ``(x, y, yaw)``."""
        return np.array([self.position, self.position, self.yaw])

    def rest(self, lower, upper) -> np.ndarray:
        """Rest pose (3,) from the loaded lower and upper poses (3,)."""
        lower = np.asarray(lower, float)
        return lower + self.fractions * (np.asarray(upper, float) - lower)

    def to_dict(self) -> dict:
        return {"position": self.position, "yaw": self.yaw}


def calibrate_springback(lower, upper, rest, default: float = 0.0) -> Springback:
    """Least-squares fractions from loaded lower, upper and rest poses, each (n, 3)
    (or (3,)); ``default`` where a rollout has no lag to spring back."""
    lower, upper, rest = (np.atleast_2d(np.asarray(a, float)) for a in (lower, upper, rest))
    lag, back = upper - lower, rest - lower

    def fit(cols):
        ll = float((lag[:, cols] ** 2).sum())
        return float((lag[:, cols] * back[:, cols]).sum()) / ll if ll > NO_LAG**2 else default

    return Springback(position=fit([0, 1]), yaw=fit([2]))
