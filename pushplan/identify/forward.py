"""FE predictions of observed columns: the observation file's commands run from the
undeformed block through :func:`pushplan.run.drive`, on a scenario whose friction
(and Young's modulus) are the parameters being identified."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..config.observations import Observations
from ..config.scenario import Scenario
from ..errors import SolverFailure
from ..run import drive
from ..run.observations import observed_values

PARAMETERS = ("mu_x", "mu_y", "angle_deg", "young")
"""Parameters that can be identified, by their scenario field names."""


class IdentificationError(SolverFailure):
    """An FE rollout of the observed commands failed for some parameter values."""


def with_parameters(scenario: Scenario, names, theta) -> Scenario:
    """``scenario`` with its fields ``names`` set to the values ``theta``."""
    return dataclasses.replace(scenario, **{k: float(v) for k, v in zip(names, theta)})


def as_files(obs) -> tuple[Observations, ...]:
    """One observation file, or several (each from its own press), as a tuple."""
    return (obs,) if isinstance(obs, Observations) else tuple(obs)


class FePredictor:
    """Predicts the observed columns of ``obs`` for parameter vectors ``theta``
    (values of ``names``) with FE rollouts on the scenario's mesh; counts them.

    Parameters
    ----------
    scenario : Scenario
        Block, mesh, material and solver settings; its friction is replaced by ``theta``.
    obs : Observations or sequence of Observations
        Several files are run one after the other, each from the undeformed block.
    names : tuple of str
        Parameter names among :data:`PARAMETERS`.
    elements : tuple of 3 int, optional
        Another mesh (e.g. a coarse one for sensitivities).
    """

    def __init__(self, scenario: Scenario, obs: Observations, names, elements=None, quadrature=None):
        self.scenario, self.obs, self.names = scenario, obs, tuple(names)
        self.elements, self.quadrature = elements, quadrature
        self.count = 0
        self.wall_time = 0.0

    def __call__(self, theta) -> np.ndarray:
        """Predicted observed columns stacked file by file, column by column, shape
        (sum over files of len(columns) * K,).

        Raises
        ------
        IdentificationError
            A step did not converge for these parameters.
        """
        sc = with_parameters(self.scenario, self.names, theta)
        model = sc.model(self.elements, self.quadrature)
        parts = []
        for obs in as_files(self.obs):
            t0 = time.perf_counter()
            run = drive(model, obs.commands)
            self.count += 1
            self.wall_time += time.perf_counter() - t0
            if not run.completed:
                f = run.summary.failure
                values = ", ".join(f"{k} = {v:.6g}" for k, v in zip(self.names, theta))
                raise IdentificationError(f"FE rollout of the observed commands failed at step {f.step} "
                                          f"({f.status}) for {values}: {f.message}")
            predicted = observed_values(run.summary.steps)
            parts += [predicted[k] for k in obs.columns]
        return np.concatenate(parts)


def stacked(obs) -> np.ndarray:
    """The observed columns (of one file or several) stacked as :class:`FePredictor` predicts them."""
    return np.concatenate([o.values[k] for o in as_files(obs) for k in o.columns])
