"""An identification at the file boundary: ``identified.json`` and ``identified.toml``
(the scenario with the estimates, ready for ``pushplan plan`` or ``simulate``)."""

from __future__ import annotations

import math

import numpy as np

from ..config.observations import Observations
from ..config.scenario import Scenario
from ..errors import InputError
from ..planning.distribution import Distribution
from .fit import Identification
from .forward import as_files
from .noise import NoiseModel


def _finite(v: float):
    """A float for JSON: None for inf / nan."""
    return float(v) if math.isfinite(v) else None


def parameters_json(result: Identification) -> dict:
    out = {}
    unc = result.uncertainty
    for j, k in enumerate(result.names):
        lo, hi = result.interval[j]
        out[k] = {"initial": float(result.initial[j]), "start": float(result.start[j]),
                  "estimate": float(result.estimate[j]), "sigma": _finite(result.sigma[j]),
                  "sigma_linearised": None if result.sigma_linear is None else _finite(result.sigma_linear[j]),
                  "interval_95": [_finite(lo), _finite(hi)],
                  "interval_method": _method(unc, j, k),
                  "identifiable": result.identifiable[j], "reason": result.reasons.get(k)}
    return out


def _method(unc, j: int, name: str) -> str:
    """Which interval is reported for parameter ``j`` and why."""
    if unc is None:
        return "linearised (Gauss-Newton covariance)"
    parts = []
    if unc.method[j] == "profile":
        r = unc.profile_ratio[j]
        parts.append(f"profile along the linearised path: chi2 rose by {min(r):.2g} of the linear rise at 2 sigma, "
                     "so the chi-square surface, not the Gauss-Newton curvature, sets the width")
    else:
        parts.append("linearised (Gauss-Newton covariance; the chi-square surface agrees at 2 sigma"
                     + ("" if np.isfinite(unc.profile_ratio[j]).all() else ", not checked") + ")")
    if unc.chi2_factor > 1.0:
        parts.append(f"inflated by the reduced chi2 {unc.chi2_factor:.3g}")
    if unc.discretisation_chi2 is not None:
        parts.append(f"plus the discretisation shift {unc.discretisation[j]:.3g} (two-mesh Richardson estimate)")
    return "; ".join(parts)


def identified_document(result: Identification, scenario: Scenario, obs: Observations, noise: NoiseModel,
                        source: str = "") -> dict:
    """The ``identified.json`` content.

    ``parameters.<name>``: ``initial`` (the scenario's value), ``start`` (the reduced-model
    estimate the FE fit starts from, or the initial value), ``estimate``, ``sigma`` (the
    reported standard deviation of :mod:`.uncertainty`, null when undetermined),
    ``sigma_linearised`` (Gauss-Newton, noise only), ``interval_95`` and ``interval_method``
    (which interval and why), ``identifiable`` and ``reason``; ``uncertainty``: the
    chi-square factor, the discretisation shift, the profile check and the warnings;
    ``correlation`` in the order of ``parameters`` (null where undetermined);
    ``residual``: chi-square of the whitened residual before / after, its reduced form
    and the RMS of the whitened residual per column; ``solver.fe_rollouts`` counts every
    FE rollout of the observed commands (residuals, with their exact Jacobian, or finite
    differences).
    """
    dof = result.n_values - len(result.names)
    corr = [[_finite(v) for v in row] for row in np.asarray(result.correlation)]
    files = as_files(obs)
    return {
        "scenario": scenario.name,
        "observations": {"file": source, "rows": sum(len(o) for o in files),
                         "columns": sorted({k for o in files for k in o.columns})},
        "noise": noise.to_dict(scenario.size),
        "parameters": parameters_json(result),
        "correlation": corr,
        "identifiable": all(result.identifiable),
        "uncertainty": None if result.uncertainty is None else result.uncertainty.to_dict(result.names),
        "residual": {"chi2_initial": result.chi2_initial, "chi2": result.chi2, "values": result.n_values,
                     "dof": dof, "reduced_chi2": result.chi2 / dof if dof > 0 else None,
                     "rms_whitened": result.residual_rms},
        "solver": {
            "method": "reduced-model prefit (elliptic limit surface, associated slip), then weighted "
                      "Levenberg-Marquardt on FE rollouts, "
                      + ("exact Jacobian (the rollouts' derivatives)" if result.exact_jacobian
                         else "forward-difference Jacobian"),
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
                        + ", ".join(f"{k} = {v:.6g}" for k, v in zip(result.names, result.estimate, strict=True)) + "]").strip()
    return d


def covariance_from_document(doc: dict) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """``(names, estimate (p,), covariance (p, p))`` of an ``identified.json`` content,
    ``C = corr * sigma sigma^T`` (an undetermined parameter gets ``inf`` variance, no covariance)."""
    p = doc["parameters"]
    names = tuple(p)
    estimate = np.array([p[k]["estimate"] for k in names], float)
    sd = np.array([math.inf if p[k]["sigma"] is None else p[k]["sigma"] for k in names], float)
    corr = np.array([[np.nan if v is None else v for v in row] for row in doc["correlation"]], float)
    finite = np.isfinite(sd)
    C = np.where(np.outer(finite, finite), np.nan_to_num(corr) * np.outer(np.where(finite, sd, 0.0),
                                                                            np.where(finite, sd, 0.0)), 0.0)
    C[~finite, ~finite] = np.inf
    return names, estimate, C


def read_identified(path) -> Distribution:
    """The parameter distribution of an ``identified.json`` file (:func:`covariance_from_document`),
    for a robust plan (:mod:`pushplan.planning.robust`).

    Raises
    ------
    InputError
        Unreadable file, not an ``identify`` document, an undetermined parameter (sigma
        null) or a covariance that is not positive semi-definite; one line naming the entry.
    """
    import json

    from .forward import PARAMETERS

    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"--identified: cannot read {path}: {e}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), dict) or not doc["parameters"] \
            or not isinstance(doc.get("correlation"), list):
        raise InputError(f"--identified: {path} is not an identified.json (no parameters / correlation)")
    for k, entry in doc["parameters"].items():
        if k not in PARAMETERS:
            raise InputError(f"--identified: {path}: parameters.{k} is not an identifiable parameter "
                             f"({', '.join(PARAMETERS)})")
        if not isinstance(entry, dict) or not isinstance(entry.get("estimate"), (int, float)) \
                or not math.isfinite(entry["estimate"]):
            raise InputError(f"--identified: {path}: parameters.{k}.estimate must be a finite number")
        if entry.get("sigma") is None:
            raise InputError(f"--identified: {path}: parameters.{k}.sigma is null (undetermined); a robust plan "
                             "needs every parameter's uncertainty (fix it at a value: identify --fit without it)")
    p = len(doc["parameters"])
    if len(doc["correlation"]) != p or any(not isinstance(r, list) or len(r) != p for r in doc["correlation"]):
        raise InputError(f"--identified: {path}: correlation must be {p} x {p}")
    try:
        names, estimate, C = covariance_from_document(doc)
    except (TypeError, ValueError) as e:
        raise InputError(f"--identified: {path}: bad sigma or correlation entry ({e})") from None
    scale = max(float(np.max(np.abs(np.diag(C)))), 1e-300)
    if not np.isfinite(C).all() or np.linalg.eigvalsh(0.5 * (C + C.T)).min() < -1e-9 * scale:
        raise InputError(f"--identified: {path}: the covariance (correlation x sigmas) is not positive semi-definite")
    return Distribution(names, estimate, C)
