"""Identifying the surface's friction (and the block's stiffness) from observed pushes.

``forward``   FE predictions of an observation file's columns for given parameters
``noise``     the noise model: one standard deviation per observed value
``prefit``    the steady-sliding (reduced-model) estimate that starts the FE fit
``fit``       weighted Levenberg-Marquardt on FE predictions, Gauss-Newton covariance,
              identifiability
``uncertainty`` the reported covariance: chi-square rule, discretisation term, profile check
``propagate`` the covariance of a predicted pose from the parameters' covariance
``design``    experiment design: push directions that make the parameters identifiable
``document``  ``identified.json`` and ``identified.toml``

A layer beside :mod:`pushplan.planning` (may import it); imports nothing from
``mujoco``, ``studies`` or ``cli``.
"""

from .fit import FIT_CHOICES, Identification, identify
from .noise import NoiseModel

__all__ = ["FIT_CHOICES", "Identification", "NoiseModel", "identify"]
