"""Reduced model of a push: the block as one elastic-plastic contact "spring".

In a push the lower face moves almost rigidly while the upper face leads it by an
elastic lag.  The reduced model keeps exactly that: a generalised drive force
``g = (f_x, f_y, tau)`` (N, N, N m) transmitted through the block, an elastic lag
between the upper- and lower-face poses

    U - P = W g,      W = diag(C, C, C_theta)   (m/N, m/N, rad/(N m)),

and a frictional limit surface in the generalised force space, elliptic in the
orthotropy frame of the plane (the paper's cone ``||M^-1 r_t|| <= r_n`` summed over
the face) and closed by the torsional limit ``tau_max``:

    F(g) = sqrt(f_1^2 / (N mu_x)^2 + f_2^2 / (N mu_y)^2 + tau^2 / tau_max^2) <= 1,

with ``(f_1, f_2)`` the force in the frame ``(t_x, t_y)``.  The lower face slips
along the normal of the limit surface (associated slip, paper eq. 23-30), so a
load step is the backward-Euler return mapping of perfect plasticity: closest-point
projection of the trial force onto the ellipsoid in the compliance metric.  In
steady sliding this reproduces the lag ``L(s) = C N M^2 s / ||M s||`` of the
elliptic law for a slip direction ``s``.

The law of a step given the force level, direction and slip is written once, as a
CasADi ``Function`` (:func:`push_law`): the planning NLP uses it symbolically, and
:func:`simulate_reduced` evaluates it numerically after the return mapping.  The
parameters are calibrated from FE rollouts (:func:`calibrate`); translation-only
models leave the torsional parameters unset and ignore rotation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fe_contact import StepReport, local_frame

from ..config.validate import number
from ..errors import InputError

PROJECTION_TOL = 1e-13
"""Relative tolerance of the scalar Newton solve of the ellipsoid projection."""


@dataclass(frozen=True)
class PushParameters:
    """Calibrated parameters of the reduced push model (SI units).

    Parameters
    ----------
    mu_x, mu_y : float
        Principal friction coefficients of the plane (> 0).
    angle : float
        Orthotropy axis ``t_x`` from world x, rad.
    normal_force : float
        Normal force carried by the lower face while pushing, N.
    compliance : float
        In-plane shear compliance of the block, lag per drive force, m/N.
    torsion_compliance : float or None
        Yaw lag per drive torque, rad/(N m); None for a translation-only model.
    max_torque : float or None
        Torque of pure torsional sliding, N m; None for a translation-only model.
    """

    mu_x: float
    mu_y: float
    angle: float
    normal_force: float
    compliance: float
    torsion_compliance: float | None = None
    max_torque: float | None = None

    def __post_init__(self):
        if (self.torsion_compliance is None) != (self.max_torque is None):
            raise InputError("torsion_compliance and max_torque go together (both set or both None)")
        positive = ("mu_x", "mu_y", "normal_force", "compliance")
        if self.torsion_compliance is not None:
            positive += ("torsion_compliance", "max_torque")
        for name in positive:
            object.__setattr__(self, name, number(name, getattr(self, name), positive=True))
        object.__setattr__(self, "angle", number("angle", self.angle))

    @property
    def rotation(self) -> bool:
        """Whether the model has the torsional degree of freedom."""
        return self.torsion_compliance is not None

    @property
    def frame(self) -> np.ndarray:
        """(2, 2) map from orthotropy-frame coordinates ``(t_x, t_y)`` to world ``(x, y)``
        (the tangential block of :func:`fe_contact.local_frame`, transposed)."""
        return local_frame(self.angle)[1:, :2].T

    @property
    def lag_scale(self) -> float:
        """Steady-sliding lag along the weaker friction axis, ``C N min(mu)``, m."""
        return self.compliance * self.normal_force * min(self.mu_x, self.mu_y)

    def to_dict(self) -> dict:
        return {
            "mu_x": self.mu_x, "mu_y": self.mu_y, "angle_deg": math.degrees(self.angle),
            "normal_force": self.normal_force, "compliance": self.compliance,
            "torsion_compliance": self.torsion_compliance, "max_torque": self.max_torque,
        }


def steady_lag(params: PushParameters, direction) -> np.ndarray:
    """Steady-sliding lag of the upper face over the lower face (translation only).

    ``L(s) = C N R M^2 R^T s / ||M R^T s||`` for a slip direction ``s``.

    Parameters
    ----------
    direction : (2,) array
        Slip direction of the lower face in world x, y (any non-zero length).

    Returns
    -------
    ndarray, shape (2,)
        Lag, m.
    """
    s = np.asarray(direction, float)
    if s.shape != (2,) or not np.all(np.isfinite(s)) or not np.any(s):
        raise ValueError(f"direction must be a finite non-zero (2,) vector, got {direction!r}")
    R = params.frame
    m = np.array([params.mu_x, params.mu_y])
    local = R.T @ s
    return params.compliance * params.normal_force * (R @ (m**2 * local)) / np.linalg.norm(m * local)


def push_law(params: PushParameters):
    """The reduced push law of one step, written once: a CasADi ``Function``
    evaluated numerically by :func:`simulate_reduced` and symbolically by the
    planning NLP (:mod:`.nlp`), as rockit does with its models.

    ``(p, a, rho, lam) -> (p_next, u_next, g)``: from the lower-face pose ``p``
    (3,) ``(x, y, yaw)``, the generalised drive force on the limit surface ``F(g) =
    rho`` in the orthotropy frame, ``g_local = rho (N mu_x a_1, N mu_y a_2,
    tau_max a_3)`` with the unit direction ``a`` (3,), and the slip multiplier
    ``lam >= 0`` (m):

        p_next = p + lam R_3 (mbar a_1 / mu_x, mbar a_2 / mu_y, mbar a_3 N / tau_max)
        u_next = p_next + R_3 W g_local,          g = R_3 g_local,

    ``mbar = sqrt(mu_x mu_y)``, ``R_3`` the orthotropy frame on ``(x, y)`` (yaw
    unchanged).  The slip is along the normal of the limit surface (associated
    slip, paper eq. 23-30); it may be non-zero only on the surface (``rho = 1``),
    which the return mapping and the NLP's complementarity enforce.  A
    translation-only model has no yaw terms (``a_3`` is ignored).  Units: m, rad,
    N, N m.
    """
    import casadi as ca

    R = ca.DM(params.frame)
    N, mx, my, C = params.normal_force, params.mu_x, params.mu_y, params.compliance
    mbar = math.sqrt(mx * my)
    p, a = ca.SX.sym("p", 3), ca.SX.sym("a", 3)
    rho, lam = ca.SX.sym("rho"), ca.SX.sym("lam")
    slip_xy = lam * (R @ ca.vertcat(mbar * a[0] / mx, mbar * a[1] / my))
    lag_xy = C * rho * N * (R @ ca.vertcat(mx * a[0], my * a[1]))
    g_xy = rho * (R @ ca.vertcat(N * mx * a[0], N * my * a[1]))
    if params.rotation:
        tau = params.max_torque
        slip_th = lam * mbar * a[2] * N / tau
        lag_th = params.torsion_compliance * rho * tau * a[2]
        g_th = rho * tau * a[2]
    else:
        slip_th = lag_th = g_th = 0
    p_next = p + ca.vertcat(slip_xy, slip_th)
    u_next = p_next + ca.vertcat(lag_xy, lag_th)
    return ca.Function("push_law", [p, a, rho, lam], [p_next, u_next, ca.vertcat(g_xy, g_th)],
                       ["p", "a", "rho", "lam"], ["p_next", "u_next", "g"])


def _return_mapping(trial: np.ndarray, w: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    """Closest point ``g`` of the ellipsoid ``sum(q g^2) <= 1`` to ``trial`` in the
    metric ``diag(w)`` (all in the orthotropy frame) and its multiplier ``gamma``:
    ``g_i = g_tr_i / (1 + gamma q_i / w_i)``, the slip being ``gamma q g``.  ``gamma >=
    0`` is found by Newton's method, which converges monotonically from 0 as the
    constraint is convex and decreasing."""
    if (q * trial**2).sum() <= 1.0:
        return trial, 0.0
    gamma = 0.0
    r = q / w
    for _ in range(200):
        d = 1.0 + gamma * r
        phi = (q * trial**2 / d**2).sum() - 1.0
        if phi <= PROJECTION_TOL:
            break
        dphi = (-2.0 * q * trial**2 * r / d**3).sum()
        gamma -= phi / dphi
    return trial / (1.0 + gamma * r), gamma


@dataclass(frozen=True)
class ReducedTrajectory:
    """Reduced-model response to a command sequence (row 0 = after the press).

    Attributes
    ----------
    upper, lower : ndarray, shape (K + 1, 3)
        Upper- and lower-face poses ``(x, y, yaw)``, m and rad.
    force : ndarray, shape (K + 1, 3)
        Generalised drive force ``(f_x, f_y, tau)`` in world axes, N and N m.
    sliding : ndarray, shape (K + 1,) of bool
        Whether the lower face slips in the step.
    """

    upper: np.ndarray
    lower: np.ndarray
    force: np.ndarray
    sliding: np.ndarray


def simulate_reduced(params: PushParameters, commands, law=None) -> ReducedTrajectory:
    """Run upper-face commands through the reduced model from the pressed, unloaded state.

    Each step is the backward-Euler return mapping (closest-point projection of the
    trial force on the limit surface in the compliance metric), whose force level
    ``rho``, direction ``a`` and slip multiplier ``lam = gamma rho / (N mbar)`` then
    go through :func:`push_law`.

    Parameters
    ----------
    commands : array, shape (K, 3)
        Upper-face increments ``(dx, dy, dtheta)``, m and rad; ``dtheta`` must be 0
        for a translation-only model.
    law : casadi.Function, optional
        ``push_law(params)``, built once by a caller that simulates often (default: built here).

    Returns
    -------
    ReducedTrajectory
    """
    u = np.asarray(commands, float)
    if u.ndim != 2 or u.shape[1] != 3 or not np.all(np.isfinite(u)):
        raise ValueError(f"commands must be a finite (K, 3) array, got shape {np.shape(commands)}")
    if not params.rotation and np.any(u[:, 2] != 0):
        raise ValueError("commands rotate the upper face but the model has no torsional parameters")
    R, n = params.frame, params.normal_force
    limits = np.array([n * params.mu_x, n * params.mu_y, params.max_torque if params.rotation else math.inf])
    w = np.array([params.compliance, params.compliance, params.torsion_compliance if params.rotation else 1.0])
    law = push_law(params) if law is None else law
    K = len(u)
    upper, lower, force = np.zeros((K + 1, 3)), np.zeros((K + 1, 3)), np.zeros((K + 1, 3))
    sliding = np.zeros(K + 1, dtype=bool)
    for k in range(K):
        upper[k + 1] = upper[k] + u[k]
        lag = upper[k + 1] - lower[k]  # trial lag: the lower face has not moved yet
        trial = np.array([*(R.T @ lag[:2]), lag[2]]) / w
        g_local, gamma = _return_mapping(trial, w, 1.0 / limits**2)
        sliding[k + 1] = gamma > 0
        scaled = g_local / limits  # F(g) = |scaled|
        rho = float(np.linalg.norm(scaled))
        a = scaled / rho if rho > 0 else np.array([1.0, 0.0, 0.0])
        lam = gamma * rho / (n * math.sqrt(params.mu_x * params.mu_y))
        p_next, _, g = law(lower[k], a, rho, lam)
        lower[k + 1], force[k + 1] = np.asarray(p_next).ravel(), np.asarray(g).ravel()
    return ReducedTrajectory(upper=upper, lower=lower, force=force, sliding=sliding)


def lower_face_torque(model, report: StepReport) -> float:
    """Drive torque on the block about the deformed lower-face centroid, N m:
    minus the moment of the contact forces (the upper face balances them)."""
    mesh = model.mesh
    X = mesh.nodes[mesh.lower] + report.displacement[mesh.lower]
    a = model.lower_area
    c = (a[:, None] * X).sum(axis=0) / a.sum()
    r = report.reaction_world
    return -float(((X[:, 0] - c[0]) * r[:, 1] - (X[:, 1] - c[1]) * r[:, 0]).sum())


def elastic_estimate(model, normal_force: float) -> dict:
    """The reduced model's spring from the block's elasticity alone, for when a rollout
    cannot calibrate it: shear ``C = h / (G A)``, torsion ``C_theta = h / (G J_p)`` with
    the polar moment ``J_p = lx ly (lx^2 + ly^2) / 12`` (m/N, rad/(N m)), and the torque
    of uniform-pressure sliding ``tau_max = N sqrt(mu_x mu_y) <|r|>`` over the lower face (N m)."""
    lx, ly, lz = model.mesh.size
    G = model.material.lame_mu
    X = model.mesh.nodes[model.mesh.lower][:, :2]
    a = model.lower_area
    mean_r = float((a * np.linalg.norm(X - (a[:, None] * X).sum(axis=0) / a.sum(), axis=1)).sum() / a.sum())
    fr = model.friction
    return {"compliance": 1.0 / model.shear_stiffness, "torsion_compliance": lz / (G * lx * ly * (lx**2 + ly**2) / 12),
            "max_torque": abs(normal_force) * math.sqrt(fr.mu_x * fr.mu_y) * mean_r}


def _ratio(num: float, den: float) -> float | None:
    """``num / den`` when it is a positive finite compliance, else None (cannot calibrate)."""
    c = num / den if den > 0 else math.nan
    return c if math.isfinite(c) and c > 0 else None


def calibrate(model, push_reports, twist_reports=None, log=None) -> PushParameters:
    """Fit the reduced model to FE rollouts on one mesh.

    Parameters
    ----------
    model : fe_contact.Model
        The model the reports come from (friction, mesh).
    push_reports : sequence of StepReport
        The push steps (after the press) of an in-plane push from the block at rest.
        The compliance is the
        least-squares ratio of the centroid lag to the drive force over all steps
        (elastic in stick and slip alike); the normal force is the last step's.
    twist_reports : sequence of StepReport, optional
        The steps of a pure rotation of the upper face from the pressed, unrotated
        state, long enough to slide: the
        torsional compliance is the least-squares ratio of the yaw lag to the drive
        torque, ``max_torque`` the last step's torque.  Without it the model is
        translation-only.
    log : callable(str), optional
        Told when a ratio is not a positive compliance (rollouts from a loaded state, a
        torque that reverses) and :func:`elastic_estimate` stands in: the FE
        correction of the planner then does the rest.  Never a negative compliance.

    Raises
    ------
    ValueError
        Empty or failed rollouts, or a rollout that transmits no force.
    """
    fr = model.friction
    if not push_reports:
        raise ValueError("push_reports is empty: calibration needs at least one push step")
    for rep in list(push_reports) + list(twist_reports or []):
        if not rep.converged:
            raise ValueError(f"calibration step {rep.step_index} did not converge ({rep.status.value})")
    lag = np.array([r.lag for r in push_reports])
    force = -np.array([r.tangential_force for r in push_reports])
    ff = float((force * force).sum())
    if ff <= 0:
        raise ValueError("calibration push transmits no tangential force (block not pressed?)")
    normal = push_reports[-1].normal_force
    fallback = elastic_estimate(model, normal)
    fitted = {"compliance": _ratio(float((lag * force).sum()), ff)}
    if twist_reports:
        theta = np.cumsum([r.command.dtheta for r in twist_reports])
        yaw = np.array([r.lower_yaw for r in twist_reports])
        torque = np.array([lower_face_torque(model, r) for r in twist_reports])
        fitted["torsion_compliance"] = _ratio(float(((theta - yaw) * torque).sum()), float((torque * torque).sum()))
        fitted["max_torque"] = abs(float(torque[-1])) or None
    for k, v in fitted.items():
        if v is None:
            fitted[k] = fallback[k]
            if log is not None:
                log(f"calibration: the rollout gives no positive {k}; the elastic estimate {fallback[k]:.4g} "
                    "stands in (the FE correction does the rest)")
    return PushParameters(mu_x=fr.mu_x, mu_y=fr.mu_y, angle=fr.angle, normal_force=normal, **fitted)
