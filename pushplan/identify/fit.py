"""Weighted least squares of FE predictions against observations.

With the whitened residual ``r(theta) = (y_FE(theta) - y_obs) / sigma`` (the noise
model of :mod:`.noise`), the estimate minimises ``||r||^2`` by Levenberg-Marquardt
(Marquardt 1963) in scaled parameters, the Jacobian ``J = dr/dtheta`` exact, from the
rollouts' derivatives (:meth:`.forward.FePredictor.jacobian`: each trial rollout brings
its Jacobian), or by forward differences of FE rollouts (one rollout per parameter and
iteration) for a predictor without them.  At the
estimate the Gauss-Newton covariance is

    Cov = (J^T J)^-1                       (computed from the SVD of J),

widened by the model's error and checked against the chi-square surface
(:mod:`.uncertainty`); the diagonal of the result gives the reported standard
deviations and its scaled form the correlation.
A parameter is *identifiable* when its standard deviation is finite and below
:data:`REL_SIGMA_LIMIT` of its value (``mu``, ``young``) or :data:`ANGLE_SIGMA_LIMIT_DEG`;
:mod:`.reasons` says why not.  The fit starts from the reduced-model estimate of
:mod:`.prefit` when the observations allow it and the FE fits it better than the
scenario's values (partial slip can mislead the reduced model), else from the scenario's.
Parameters not identifiable at the start are kept fixed at the scenario's value (a
fit would only chase the noise along them) and the others fitted; if one becomes identifiable at the estimate,
all are fitted again from there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fe_contact import MU_MAX

from ..config.scenario import Scenario
from ..errors import InputError
from .forward import PARAMETERS, FePredictor, IdentificationError, as_files, stacked, with_parameters
from .noise import NoiseModel
from .prefit import nearest_angle, prefit
from .reasons import identifiability
from .uncertainty import (REFINEMENT, Z95, Uncertainty, chi2_factor, chi2_warning, combine, discretisation_shift,
                          profile_sigmas)

FIT_CHOICES = PARAMETERS
DEFAULT_FIT = ("mu_x", "mu_y", "angle_deg")
MAX_ITERATIONS = 15
STEP_TOL = 1e-5
"""Stop when the scaled step is below this (units: mu 0.1, angle 1 deg, young itself)."""
STAT_STEP_TOL = 1e-2
"""... or when every component of the step is below this fraction of its standard deviation."""
FD_STEP = {"mu_x": 1e-5, "mu_y": 1e-5, "angle_deg": 1e-3, "young": 1e-6}
"""Forward-difference steps (absolute; young relative), well above the solver's noise."""
SINGULAR_RTOL = 1e-9
"""Singular values of the scaled Jacobian below this fraction of the largest are null directions."""
MU_FLOOR = 1e-4


@dataclass(frozen=True)
class Identification:
    """An identification's result (SI units; angles in degrees).

    ``sigma`` is ``inf`` for a parameter in a null direction of the Jacobian;
    ``correlation`` has ``nan`` there.  ``chi2`` = ``||r||^2`` of the whitened residual.
    """

    names: tuple[str, ...]
    initial: np.ndarray
    start: np.ndarray
    estimate: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray
    identifiable: tuple[bool, ...]
    reasons: dict
    chi2_initial: float
    chi2: float
    n_values: int
    residual_rms: dict
    iterations: int
    converged: bool
    fe_rollouts: int
    jacobian: np.ndarray = field(repr=False)
    wall_time: float = 0.0
    prefit_used: bool = False
    sigma_linear: np.ndarray | None = None
    uncertainty: Uncertainty | None = field(default=None, repr=False)
    exact_jacobian: bool = False
    """The Jacobian was exact (the rollouts' derivatives), else forward differences."""

    @property
    def interval(self) -> np.ndarray:
        """(p, 2) 95 % bounds (``estimate +- 1.96 sigma``)."""
        if self.uncertainty is not None:
            return self.uncertainty.interval
        return np.column_stack([self.estimate - Z95 * self.sigma, self.estimate + Z95 * self.sigma])

    def value(self, name: str) -> float:
        return float(self.estimate[self.names.index(name)])

    def scenario(self, scenario: Scenario) -> Scenario:
        """``scenario`` with the estimates."""
        return with_parameters(scenario, self.names, self.estimate)


def scales(names, theta) -> np.ndarray:
    """Parameter scales of the LM step and the identifiability tests."""
    table = {"mu_x": 0.1, "mu_y": 0.1, "angle_deg": 1.0}
    return np.array([table.get(k, abs(t)) for k, t in zip(names, theta, strict=True)])


def _residual(predict, y, sigma, theta) -> np.ndarray:
    return (predict(theta) - y) / sigma


def _jacobian(predict, y, sigma, names, theta, r0, free=None) -> np.ndarray:
    """``dr/dtheta`` (n_values, n_free) of the parameters ``free`` (a mask; all by
    default): exact if ``predict`` has derivatives, else forward differences."""
    free = np.ones(len(names), bool) if free is None else np.asarray(free)
    if getattr(predict, "exact", False):
        return predict.jacobian(theta)[:, free] / sigma[:, None]
    J = np.empty((r0.size, int(free.sum())))
    for col, j in enumerate(np.flatnonzero(free)):
        k = names[j]
        h = FD_STEP[k] * (abs(theta[j]) if k == "young" else 1.0)
        t = theta.copy()
        t[j] += h
        J[:, col] = (_residual(predict, y, sigma, t) - r0) / h
    return J


def _clip(names, theta) -> np.ndarray:
    t = theta.copy()
    for j, k in enumerate(names):
        if k in ("mu_x", "mu_y"):
            t[j] = min(max(t[j], MU_FLOOR), MU_MAX)  # fe_contact's range of a coefficient
        elif k == "young":
            t[j] = max(t[j], 1e-3 * abs(theta[j]))
    return t


def _lm_step(J, r, D, lam) -> np.ndarray:
    Js = J * D
    A = Js.T @ Js
    g = Js.T @ r
    damping = lam * np.diag(np.maximum(np.diag(A), 1e-12 * max(np.trace(A), 1e-300)))
    return -D * np.linalg.solve(A + damping, g)


def levenberg_marquardt(predict, y, sigma, names, theta, free, log=None, J=None):
    """Minimise ``||(predict(theta) - y) / sigma||^2`` over the parameters ``free`` (a
    boolean mask; the others stay fixed); ``J`` the Jacobian at ``theta`` if known.
    Returns ``(theta, r, J, iterations, converged)`` with the full Jacobian at the end."""
    r = _residual(predict, y, sigma, theta)
    lam, converged, it = 1e-3, False, 0
    sub = tuple(k for k, f in zip(names, free, strict=True) if f)

    def full(t_free):
        t = theta_fixed.copy()
        t[free] = t_free
        return t

    theta_fixed = theta.copy()
    for it in range(1, MAX_ITERATIONS + 1):
        Jf = J[:, free] if J is not None else _jacobian(predict, y, sigma, names, theta, r, free)
        J = None
        D = scales(sub, theta[free])
        for _ in range(8):
            trial = _clip(names, full(theta[free] + _lm_step(Jf, r, D, lam)))
            r_trial = _residual(predict, y, sigma, trial)
            if r_trial @ r_trial <= r @ r:
                break
            lam *= 4.0
        else:
            converged = True  # no descent along the damped steps: a minimum to the FD accuracy
            break
        small = np.max(np.abs((trial - theta)[free] / D)) < STEP_TOL or _negligible(Jf, D, (trial - theta)[free])
        theta, r, lam = trial, r_trial, max(lam / 3.0, 1e-7)
        if log is not None:
            log(f"  LM iteration {it}: chi2 {r @ r:.6g}, " + ", ".join(f"{k} = {v:.6g}" for k, v in zip(names, theta, strict=True)))
        if small:
            converged = True
            break
    J = _jacobian(predict, y, sigma, names, theta, r)
    return theta, r, J, it, converged


def _negligible(J, D, step) -> bool:
    """Whether every component of ``step`` is below :data:`STAT_STEP_TOL` of its
    Gauss-Newton standard deviation: the estimate no longer moves on the scale its
    noise can resolve (a flat, non-smooth chi-square would otherwise run out of iterations)."""
    cov, undetermined = covariance(J, D)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return bool(np.all(undetermined | (np.abs(step) < STAT_STEP_TOL * sd)))


def covariance(J: np.ndarray, D: np.ndarray):
    """Gauss-Newton covariance ``(J^T J)^-1`` (scaled SVD) and which parameters lie in
    null directions (their variance is infinite)."""
    U, s, Vt = np.linalg.svd(J * D, full_matrices=False)
    null = s <= SINGULAR_RTOL * s.max() if s.size and s.max() > 0 else np.ones(len(s), bool)
    inv = np.where(null, 0.0, 1.0 / np.where(null, 1.0, s) ** 2)
    cov_s = (Vt.T * inv) @ Vt
    undetermined = (np.abs(Vt[null]) > 1e-6).any(axis=0) if null.any() else np.zeros(J.shape[1], bool)
    return cov_s * np.outer(D, D), undetermined


def _correlation(cov, undetermined) -> np.ndarray:
    d = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(d, d)
    corr[undetermined, :] = np.nan
    corr[:, undetermined] = np.nan
    return corr


def _rms(obs, r: np.ndarray) -> dict:
    """RMS of the whitened residual per column, over every file."""
    squares: dict = {}
    i = 0
    for o in as_files(obs):
        for k in o.columns:
            squares.setdefault(k, []).append(r[i:i + len(o)] ** 2)
            i += len(o)
    return {k: float(np.sqrt(np.mean(np.concatenate(v)))) for k, v in squares.items()}


def identify(scenario: Scenario, obs, noise: NoiseModel | None = None, fit=DEFAULT_FIT,
             log=None, model_error: bool = True, exact: bool = True) -> Identification:
    """Estimate the parameters ``fit`` from ``obs`` (one :class:`Observations` or several,
    each from its own press; see the module docstring).  ``model_error`` False skips the
    refined-mesh rollout and the chi-square profile checks of :mod:`.uncertainty` (the
    chi-square rule still applies).  ``exact`` False takes the Jacobian by forward
    differences.

    Raises
    ------
    InputError
        No observed column, an unknown parameter, or fewer values than parameters.
    IdentificationError
        An FE rollout failed.
    """
    t0 = time.perf_counter()
    noise = noise or NoiseModel()
    names = tuple(fit)
    y, sigma = _checked_values(scenario, obs, noise, names)
    predict = FePredictor(scenario, obs, names, exact=exact)
    initial, start, used, chi2_initial, r0 = _starting_point(scenario, obs, noise, names, predict, y, sigma)
    theta, r, J, iterations, converged, free = _fit(predict, y, sigma, names, initial, start, r0, obs, noise, log)
    theta = _normalise_angle(names, theta, scenario.angle_deg)
    _, _, cov0, sd0, undetermined = _assess(names, theta, J, obs, noise)
    fitted_rollouts = predict.count
    unc = _uncertainty(scenario, obs, names, theta, J, r, y, sigma, cov0, free & ~undetermined, predict, model_error)
    cov = unc.covariance
    flags, reasons, cov, sd, undetermined = _assess(names, theta, J, obs, noise, cov)
    if log is not None:
        for w in unc.warnings:
            log("  warning: " + w)
    return Identification(
        names=names, initial=initial, start=start, estimate=theta, sigma=sd,
        correlation=_correlation(cov, undetermined), identifiable=flags, reasons=reasons,
        chi2_initial=chi2_initial, chi2=float(r @ r), n_values=int(y.size), residual_rms=_rms(obs, r),
        iterations=iterations, converged=converged, fe_rollouts=fitted_rollouts + unc.fe_rollouts, jacobian=J,
        wall_time=time.perf_counter() - t0, prefit_used=used, sigma_linear=sd0, uncertainty=unc,
        exact_jacobian=predict.exact,
    )


def _checked_values(scenario: Scenario, obs, noise: NoiseModel, names) -> tuple[np.ndarray, np.ndarray]:
    """The stacked observed values ``y`` and their standard deviations ``sigma`` (n_values,),
    after checking that ``names`` are parameters and the observations can determine them."""
    for k in names:
        if k not in FIT_CHOICES:
            raise InputError(f"--fit {k}: unknown parameter (choose from {', '.join(FIT_CHOICES)})")
    if not any(o.columns for o in as_files(obs)):
        raise InputError("observations: no observed column (lower_x, ..., force_z) to fit")
    y, sigma = stacked(obs), noise.sigma(obs, scenario.size)
    if y.size < len(names):
        raise InputError(f"observations: {y.size} values cannot determine {len(names)} parameters")
    return y, sigma


def _starting_point(scenario: Scenario, obs, noise: NoiseModel, names, predict, y, sigma):
    """Where the fit starts: the reduced model's prefit of the friction when it fits the FE
    better than the scenario's values, else those.  Returns the scenario's values, the
    start, whether the prefit was used, the chi-square at the scenario's values and the
    whitened residual at the start."""
    initial = np.array([getattr(scenario, k) for k in names], float)
    start, used = initial.copy(), False
    if {"mu_x", "mu_y", "angle_deg"} <= set(names):
        guess = prefit(obs, [getattr(scenario, k) for k in ("mu_x", "mu_y", "angle_deg")], noise.pose_noise)
        if guess is not None:
            for k, v in zip(("mu_x", "mu_y", "angle_deg"), guess, strict=True):
                start[names.index(k)] = v
            used = True
    r_initial = _residual(predict, y, sigma, initial)
    chi2_initial = float(r_initial @ r_initial)
    r0 = _residual(predict, y, sigma, start)
    if used and r0 @ r0 > chi2_initial:  # the reduced model misled (partial slip): start where the FE fits better
        start, r0, used = initial.copy(), r_initial, False
    return initial, start, used, chi2_initial, r0


def _fit(predict, y, sigma, names, initial, start, r0, obs, noise: NoiseModel, log):
    """Levenberg-Marquardt from ``start`` on the parameters identifiable there (the others
    kept at the scenario's value, written into ``start``), then on all of them if the fit
    made another identifiable.  Returns ``theta, r, J, iterations, converged`` and the mask of
    the parameters fitted last."""
    J0 = _jacobian(predict, y, sigma, names, start, r0)
    free = np.array(_flags(names, start, J0, obs, noise))
    if not free.any():
        free[:] = True
    if not free.all():  # kept at the scenario's value: the prefit's value along them is arbitrary
        start[~free] = initial[~free]
        J0 = None
        if log is not None:
            log("  not identifiable at the start, kept at the scenario's value: "
                + ", ".join(k for k, f in zip(names, free, strict=True) if not f))
    theta, r, J, iterations, converged = levenberg_marquardt(predict, y, sigma, names, start, free, log, J0)
    flags, _, _, _, _ = _assess(names, theta, J, obs, noise)
    if not free.all() and any(f and not fr for f, fr in zip(flags, free, strict=True)):
        free[:] = True
        theta, r, J, more, converged = levenberg_marquardt(predict, y, sigma, names, theta, free, log, J)
        iterations += more
    return theta, r, J, iterations, converged, free


def _uncertainty(scenario, obs, names, theta, J, r, y, sigma, cov0, check, predict, model_error) -> Uncertainty:
    """The reported covariance of :mod:`.uncertainty` at the estimate."""
    dof = y.size - len(names)
    chi2 = float(r @ r)
    s2 = chi2_factor(chi2, dof)
    shift, mesh_chi2, count = np.zeros(len(names)), None, predict.count
    ratios, sd_profile = np.full((len(names), 2), np.nan), np.sqrt(np.maximum(np.diag(cov0), 0.0))
    fine, notes = None, []
    if model_error:
        fine = FePredictor(scenario, obs, names, elements=tuple(REFINEMENT * e for e in scenario.elements),
                           exact=False)  # one value, no Jacobian
        try:
            shift, mesh_chi2 = discretisation_shift(J, sigma, r * sigma + y, fine(theta), cov0)
        except IdentificationError as e:
            notes.append(f"no discretisation term: the refined-mesh rollout failed ({e})")

        def chi2_at(t):
            try:
                return float(np.sum(_residual(predict, y, sigma, _clip(names, t)) ** 2))
            except IdentificationError:
                return np.inf  # a rollout that fails this far out bounds the interval

        ratios, sd_profile = profile_sigmas(chi2_at, theta, cov0, chi2, check)
    C, interval, method = combine(names, theta, cov0, s2, shift, sd_profile, ratios)
    warning = chi2_warning(chi2, dof, s2, mesh_chi2)
    return Uncertainty(sigma=np.sqrt(np.maximum(np.diag(C), 0.0)), interval=interval, method=method, covariance=C,
                       chi2_factor=s2, discretisation=shift, discretisation_chi2=mesh_chi2, profile_ratio=ratios,
                       warnings=tuple(notes) + ((warning,) if warning else ()),
                       fe_rollouts=predict.count - count + (fine.count if fine else 0))


def _assess(names, theta, J, obs, noise, cov=None):
    """Covariance (the Gauss-Newton one unless ``cov`` is given), standard deviations and
    identifiability at ``theta``."""
    cov0, undetermined = covariance(J, scales(names, theta))
    cov = cov0 if cov is None else cov
    sd = np.where(undetermined, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    flags, reasons = identifiability(names, theta, sd, obs, noise.pose_noise, cov)
    return flags, reasons, cov, sd, undetermined


def _flags(names, theta, J, obs, noise) -> tuple[bool, ...]:
    return _assess(names, theta, J, obs, noise)[0]


def _normalise_angle(names, theta, reference_deg: float) -> np.ndarray:
    """The orthotropy axis is a line: its angle modulo 180 deg, within 90 deg of the scenario's."""
    t = theta.copy()
    if "angle_deg" in names:
        j = names.index("angle_deg")
        t[j] = nearest_angle(t[j], reference_deg)
    return t
