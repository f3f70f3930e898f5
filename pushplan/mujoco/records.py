"""What every model of the comparison reports per command: drive, face centroid
displacements, yaw, twist and deviation (:class:`ComparisonStep`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fe_contact import twist_angle


@dataclass(frozen=True)
class ComparisonStep:
    """One command of one compared model, world frame (m, rad).

    Attributes
    ----------
    step : int
        1-based command index.
    drive : ndarray, shape (3,)
        Displacement of the gripper-carried upper-face centre (or the commanded one).
    upper, lower : ndarray, shape (3,)
        Block face centroid displacements.
    lower_yaw : float
        Lower-face yaw from its reference pose.
    twist : float
        In-plane angle from ``upper`` to ``lower`` (the block's deformation twist).
    deviation : float
        In-plane angle from ``drive`` to ``lower``.
    """

    step: int
    drive: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    lower_yaw: float
    twist: float
    deviation: float

    @classmethod
    def measure(cls, step: int, drive, upper, lower, lower_yaw: float, scale: float) -> ComparisonStep:
        """The record of displacements ``drive``, ``upper``, ``lower``; ``scale`` (m, the
        block size) sets below which a displacement has no direction (zero angles)."""
        return cls(step, drive, upper, lower, lower_yaw, twist_angle(upper, lower, scale),
                   twist_angle(drive, lower, scale))

    def to_dict(self) -> dict:
        return {
            "step": self.step, "drive": self.drive, "upper": self.upper, "lower": self.lower,
            "lower_yaw_deg": math.degrees(self.lower_yaw), "twist_deg": math.degrees(self.twist),
            "deviation_deg": math.degrees(self.deviation),
        }
