"""The noise model of observations: independent Gaussian errors with one standard
deviation per observed value.

    pose:   sigma = pose_noise (m) on lower_x, lower_y;
            sigma = yaw_noise (deg) on lower_yaw_deg, by default the angle that moves a
            corner of the lower face by pose_noise: degrees(pose_noise / (min(lx, ly) / 2));
    force:  sigma_i = max(sqrt(force_noise^2 + (force_noise_rel * |f_i|)^2), force_resolution)
            (N) on force_x, _y, _z: absolute and relative noise add in quadrature, and no
            value is known better than the sensor resolves (``--force-noise 0`` with a
            relative noise would otherwise give a press row's ~1e-15 N forces a sigma of
            ~1e-17 N and let them dominate the fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config.observations import FORCE_COLUMNS, OBSERVED_COLUMNS, Observations
from ..config.validate import number
from ..errors import InputError
from ..limits import MAX_FORCE_NOISE, MAX_FORCE_NOISE_REL, MAX_POSE_NOISE, MIN_POSE_NOISE, MIN_YAW_NOISE_DEG


@dataclass(frozen=True)
class NoiseModel:
    """Standard deviations of the observation errors (SI units; yaw in degrees).

    ``yaw_noise_deg`` None: derived from ``pose_noise`` and the block (module docstring).
    """

    pose_noise: float = 1e-6
    force_noise: float = 1.0
    force_noise_rel: float = 0.01
    yaw_noise_deg: float | None = None
    force_resolution: float = 1e-3

    def __post_init__(self):
        if not MIN_POSE_NOISE <= number("pose_noise", self.pose_noise, positive=True) <= MAX_POSE_NOISE:
            raise InputError(f"pose_noise must be from {MIN_POSE_NOISE} to {MAX_POSE_NOISE} m, got {self.pose_noise}")
        number("force_noise", self.force_noise, nonneg=True, maximum=MAX_FORCE_NOISE)
        number("force_noise_rel", self.force_noise_rel, nonneg=True, maximum=MAX_FORCE_NOISE_REL)
        number("force_resolution", self.force_resolution, positive=True)
        if self.yaw_noise_deg is not None and number("yaw_noise_deg", self.yaw_noise_deg,
                                                     positive=True) < MIN_YAW_NOISE_DEG:
            raise InputError(f"yaw_noise_deg must be >= {MIN_YAW_NOISE_DEG}, got {self.yaw_noise_deg}")

    def yaw_sigma_deg(self, size) -> float:
        if self.yaw_noise_deg is not None:
            return self.yaw_noise_deg
        return math.degrees(self.pose_noise / (0.5 * min(size[0], size[1])))

    def sigma(self, obs: Observations, size) -> np.ndarray:
        """Standard deviations stacked like :func:`~pushplan.identify.forward.stacked`
        (one file, or several in order).

        Raises
        ------
        InputError
            A file without an observed column (the commands only).
        """
        if not isinstance(obs, Observations):
            return np.concatenate([self.sigma(o, size) for o in obs])
        if not obs.columns:
            raise InputError("the observations hold the commands only: identification needs at least one observed "
                             f"column ({', '.join(OBSERVED_COLUMNS)})")
        parts = []
        for k in obs.columns:
            v = obs.values[k]
            if k in FORCE_COLUMNS:
                s = np.maximum(np.hypot(self.force_noise, self.force_noise_rel * np.abs(v)), self.force_resolution)
            elif k == "lower_yaw_deg":
                s = np.full(v.shape, self.yaw_sigma_deg(size))
            else:
                s = np.full(v.shape, self.pose_noise)
            parts.append(s)
        return np.concatenate(parts)

    def to_dict(self, size) -> dict:
        return {"pose_noise": self.pose_noise, "yaw_noise_deg": self.yaw_sigma_deg(size),
                "force_noise": self.force_noise, "force_noise_rel": self.force_noise_rel,
                "force_resolution": self.force_resolution,
                "force_rule": "max(hypot(force_noise, force_noise_rel |f|), force_resolution)"}
