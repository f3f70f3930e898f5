"""FE predictions of observed columns: the observation file's commands run from the
undeformed block through :func:`pushplan.run.drive`, on a scenario whose friction
(and Young's modulus) are the parameters being identified."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from fe_contact import applicable_parameters, rollout_derivatives

from ..config.observations import Observations
from ..config.scenario import Scenario
from ..errors import SolverFailure
from ..run import drive
from ..run.observations import observed_values

PARAMETERS = ("mu_x", "mu_y", "angle_deg", "young")
"""Parameters that can be identified, by their scenario field names."""
_FE_PARAMETER = {"mu_x": ("mu_x", 1.0), "mu_y": ("mu_y", 1.0), "angle_deg": ("angle", math.pi / 180.0),
                 "young": ("young", 1.0)}
"""fe_contact's name of each parameter and d(its value) / d(scenario value)."""
_FE_OUTPUT = {"lower_x": (0, 1.0), "lower_y": (1, 1.0), "lower_yaw_deg": (2, 180.0 / math.pi), "force_x": (3, 1.0),
              "force_y": (4, 1.0), "force_z": (5, 1.0)}
"""Row of each observed column among fe_contact's rollout outputs, and its factor
(degrees; the observed force is the gripper's on the block, ``upper_force``)."""


class IdentificationError(SolverFailure):
    """An FE rollout of the observed commands failed for some parameter values."""


def with_parameters(scenario: Scenario, names, theta) -> Scenario:
    """``scenario`` with its fields ``names`` set to the values ``theta``."""
    return dataclasses.replace(scenario, **{k: float(v) for k, v in zip(names, theta, strict=True)})


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
    exact : bool
        Predict with the rollouts' exact derivatives (:func:`fe_contact.rollout_derivatives`),
        kept for :meth:`jacobian` at the same ``theta``; False: plain rollouts
        (the Jacobian by finite differences).  Observations with release
        steps are always predicted plainly.
    """

    def __init__(self, scenario: Scenario, obs: Observations, names, elements=None, quadrature=None,
                 exact: bool = True):
        self.scenario, self.obs, self.names = scenario, obs, tuple(names)
        self.elements, self.quadrature = elements, quadrature
        self.exact = exact
        if self.exact and "young" in self.names:  # material derivatives: every law and element of fe_contact
            self.exact = "young" in applicable_parameters(scenario.model(elements, quadrature))
        self.count = 0
        self.wall_time = 0.0
        self._last = (None, None, None)

    def __call__(self, theta) -> np.ndarray:
        """Predicted observed columns stacked file by file, column by column, shape
        (sum over files of len(columns) * K,).

        Raises
        ------
        IdentificationError
            A step did not converge for these parameters.
        """
        if self.exact:
            return self._derivatives(theta)[0]
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
                values = ", ".join(f"{k} = {v:.6g}" for k, v in zip(self.names, theta, strict=True))
                raise IdentificationError(f"FE rollout of the observed commands failed at step {f.step} "
                                          f"({f.status}) for {values}: {f.message}")
            predicted = observed_values(run.summary.steps)
            parts += [predicted[k] for k in obs.columns]
        return np.concatenate(parts)

    def jacobian(self, theta) -> np.ndarray:
        """Exact ``d prediction / d theta``, shape (number of predicted values, len(names)) (``exact`` only)."""
        return self._derivatives(theta)[1]

    def _derivatives(self, theta):
        """Prediction and its Jacobian at ``theta`` from one rollout with derivatives per
        file (the last ``theta``'s kept)."""
        key = np.asarray(theta, float).tobytes()
        if self._last[0] != key:
            sc = with_parameters(self.scenario, self.names, theta)
            model = sc.model(self.elements, self.quadrature)
            fe_names = [_FE_PARAMETER[k][0] for k in self.names]
            factors = np.array([_FE_PARAMETER[k][1] for k in self.names])
            values, rows = [], []
            for obs in as_files(self.obs):
                t0 = time.perf_counter()
                result = rollout_derivatives(model, obs.commands, parameters=fe_names)
                self.count += 1
                self.wall_time += time.perf_counter() - t0
                if not result.converged:
                    text = ", ".join(f"{k} = {v:.6g}" for k, v in zip(self.names, theta, strict=True))
                    raise IdentificationError(f"FE rollout of the observed commands failed "
                                              f"({result.status.value}) for {text}: {result.message}")
                for i, f in (_FE_OUTPUT[k] for k in obs.columns):
                    values.append(f * result.outputs[:, i])
                    rows.append(f * result.d_parameters[:, i, :] * factors)
            self._last = (key, np.concatenate(values), np.vstack(rows))
        return self._last[1].copy(), self._last[2].copy()


def stacked(obs) -> np.ndarray:
    """The observed columns (of one file or several) stacked as :class:`FePredictor` predicts them."""
    return np.concatenate([o.values[k] for o in as_files(obs) for k in o.columns])
