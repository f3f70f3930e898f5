"""An identification at the file boundary: ``identified.json`` and ``identified.toml``
(the scenario with the estimates, ready for ``pushplan plan`` or ``simulate``)."""

from __future__ import annotations

import math

import numpy as np

from ..config.observations import Observations
from ..config.scenario import Scenario
from .fit import Identification
from .noise import NoiseModel


def _finite(v: float):
    """A float for JSON: None for inf / nan."""
    return float(v) if math.isfinite(v) else None


def parameters_json(result: Identification) -> dict:
    out = {}
    for j, k in enumerate(result.names):
        out[k] = {"initial": float(result.initial[j]), "start": float(result.start[j]),
                  "estimate": float(result.estimate[j]), "sigma": _finite(result.sigma[j]),
                  "identifiable": result.identifiable[j], "reason": result.reasons.get(k)}
    return out


def identified_document(result: Identification, scenario: Scenario, obs: Observations, noise: NoiseModel,
                        source: str = "") -> dict:
    """The ``identified.json`` content.

    ``parameters.<name>``: ``initial`` (the scenario's value), ``start`` (the reduced-model
    estimate the FE fit starts from, or the initial value), ``estimate``, ``sigma``
    (Gauss-Newton standard deviation, null when undetermined), ``identifiable`` and
    ``reason``; ``correlation`` in the order of ``parameters`` (null where undetermined);
    ``residual``: chi-square of the whitened residual before / after, its reduced form
    and the RMS of the whitened residual per column; ``solver.fe_rollouts`` counts every
    FE rollout of the observed commands (residuals and finite differences).
    """
    dof = result.n_values - len(result.names)
    corr = [[_finite(v) for v in row] for row in np.asarray(result.correlation)]
    return {
        "scenario": scenario.name,
        "observations": {"file": source, "rows": len(obs), "columns": list(obs.columns)},
        "noise": noise.to_dict(scenario.size),
        "parameters": parameters_json(result),
        "correlation": corr,
        "identifiable": all(result.identifiable),
        "residual": {"chi2_initial": result.chi2_initial, "chi2": result.chi2, "values": result.n_values,
                     "dof": dof, "reduced_chi2": result.chi2 / dof if dof > 0 else None,
                     "rms_whitened": result.residual_rms},
        "solver": {
            "method": "reduced-model prefit (elliptic limit surface, associated slip), then weighted "
                      "Levenberg-Marquardt on FE rollouts, forward-difference Jacobian",
            "prefit_used": result.prefit_used, "iterations": result.iterations, "converged": result.converged,
            "fe_rollouts": result.fe_rollouts,
            "mesh": {"elements": list(scenario.elements), "quadrature": scenario.quadrature},
            "wall_time_s": result.wall_time,
        },
    }


def identified_scenario(result: Identification, scenario: Scenario) -> dict:
    """The scenario's tables with the estimates (``identified.toml``)."""
    sc = result.scenario(scenario)
    d = sc.to_dict()
    d["description"] = (f"{scenario.description} [identified: "
                        + ", ".join(f"{k} = {v:.6g}" for k, v in zip(result.names, result.estimate)) + "]").strip()
    return d
