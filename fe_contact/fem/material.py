"""Isotropic hyperelastic laws, chosen by name: stress ``S(F)``, its tangent
``dS/dE``, the stored energy and the stability of the law.

``"stvk"`` -- St Venant-Kirchhoff, the paper's (Feng et al. 2006, eq. 5):

    W = lambda/2 tr(E)^2 + mu E:E,        S = lambda tr(E) I + 2 mu E,
    D_IJKL = lambda d_IJ d_KL + mu (d_IK d_JL + d_IL d_JK).

It softens in compression: the uniaxial force of a bar ``E_y (l^3 - l) / 2``
peaks at the stretch ``l = 1/sqrt(3)`` and the law is unstable beyond.

``"neo_hookean"`` -- compressible Neo-Hookean, Bonet & Wood, *Nonlinear
Continuum Mechanics for Finite Element Analysis*, 2nd ed. (2008), eq. (6.27-6.29):

    W = mu/2 (tr C - 3) - mu ln J + lambda/2 (ln J)^2,
    S = mu (I - C^-1) + lambda ln(J) C^-1,
    D_IJKL = lambda C^-1_IJ C^-1_KL + (mu - lambda ln J) (C^-1_IK C^-1_JL + C^-1_IL C^-1_JK),

with ``C = F^T F`` and ``J = det F``.  The volumetric term ``-mu ln J +
lambda/2 (ln J)^2`` makes ``W -> inf`` as ``J -> 0``: no compression inverts
it.

``"hyperfoam"`` -- the Ogden-Hill compressible foam of Storakers (J. Mech.
Phys. Solids 34 (1986) 125-145) with one term and exponent ``alpha = 2``:

    W = mu/2 [tr C - 3 + (J^(-2 beta) - 1) / beta],    beta = nu / (1 - 2 nu),
    S = mu (I - J^(-2 beta) C^-1),
    D_IJKL = mu J^(-2 beta) [2 beta C^-1_IJ C^-1_KL + C^-1_IK C^-1_JL + C^-1_IL C^-1_JK].

Its Poisson's ratio is ``nu`` at every strain in uniaxial stress, ``l_t =
l^(-nu)`` (the foam's own ``beta``); at ``nu = 0`` it is the Neo-Hookean law
with ``lambda = 0``.  All three laws reduce to linear elasticity with the Lame
parameters ``lambda``, ``mu`` at small strain (``2 mu beta = lambda``), so
``Material.young`` / ``poisson`` mean the same thing for all.

Shapes: ``F`` is ``(..., 3, 3)``; ``S`` ``(..., 3, 3)`` Pa; ``D``
``(..., 3, 3, 3, 3)`` Pa; energies ``(...)`` J/m^3.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LAWS", "check_law", "green_lagrange", "stress", "stress_and_tangent", "stress_moduli_derivatives",
           "energy_density", "principal_stiffness"]

LAWS = ("stvk", "neo_hookean", "hyperfoam")
"""Names of the constitutive laws."""

_I3 = np.eye(3)


def check_law(name) -> str:
    """``name`` if it is one of :data:`LAWS`, else ValueError naming it."""
    if name not in LAWS:
        raise ValueError(f"material model must be one of {LAWS}, got {name!r}")
    return name


def green_lagrange(F) -> np.ndarray:
    """Green-Lagrange strain ``E = (F^T F - I) / 2``.

    Parameters
    ----------
    F : array_like, shape (..., 3, 3)
        Deformation gradients.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    F = np.asarray(F, dtype=np.float64)
    if F.shape[-2:] != (3, 3):
        raise ValueError(f"F must have shape (..., 3, 3), got {F.shape}")
    # Written with H = F - I so small strains do not lose digits to I - I.
    H = F - _I3
    return 0.5 * (H + np.swapaxes(H, -1, -2) + np.einsum("...kI,...kJ->...IJ", H, H))


def _log_j_and_cinv(F):
    J = _det(F)
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    return np.log(J), np.linalg.inv(C)


def _det(F):
    """``det F``; NaN where it is not positive (no energy there: an inverted element)."""
    J = np.linalg.det(F)
    return np.where(J > 0, J, np.nan)


def stress(law: str, F, lam: float, mu: float) -> np.ndarray:
    """Second Piola-Kirchhoff stress ``S`` (..., 3, 3), Pa, of ``law`` at ``F`` (..., 3, 3)."""
    if law == "stvk":
        E = green_lagrange(F)
        return lam * np.trace(E, axis1=-2, axis2=-1)[..., None, None] * _I3 + 2.0 * mu * E
    check_law(law)
    log_j, Ci = _log_j_and_cinv(F)
    if law == "hyperfoam":
        return mu * (_I3 - np.exp(-2.0 * _beta(lam, mu) * log_j)[..., None, None] * Ci)
    return mu * (_I3 - Ci) + lam * log_j[..., None, None] * Ci


def _beta(lam: float, mu: float) -> float:
    """The foam's ``beta = nu / (1 - 2 nu) = lambda / (2 mu)``."""
    return lam / (2.0 * mu)


def stress_and_tangent(law: str, F, lam: float, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """``S`` (..., 3, 3), Pa, and the material tangent ``D = dS/dE`` (..., 3, 3, 3, 3), Pa."""
    S = stress(law, F, lam, mu)
    shape = S.shape[:-2]
    if law == "stvk":
        D = (lam * np.einsum("IJ,KL->IJKL", _I3, _I3)
             + mu * (np.einsum("IK,JL->IJKL", _I3, _I3) + np.einsum("IL,JK->IJKL", _I3, _I3)))
        return S, np.broadcast_to(D, shape + (3, 3, 3, 3))
    log_j, Ci = _log_j_and_cinv(F)
    if law == "hyperfoam":
        beta = _beta(lam, mu)
        scale, coeff = 2.0 * beta * mu * np.exp(-2.0 * beta * log_j), mu * np.exp(-2.0 * beta * log_j)
    else:
        scale, coeff = np.full(log_j.shape, lam), mu - lam * log_j
    coeff = coeff[..., None, None, None, None]
    D = scale[..., None, None, None, None] * np.einsum("...IJ,...KL->...IJKL", Ci, Ci) + coeff * (
        np.einsum("...IK,...JL->...IJKL", Ci, Ci) + np.einsum("...IL,...JK->...IJKL", Ci, Ci))
    return S, D


def stress_moduli_derivatives(law: str, F, lam: float, mu: float) -> np.ndarray:
    """``(dS/dlambda, dS/dmu)`` at fixed ``F`` (2, ..., 3, 3), dimensionless.

    St Venant-Kirchhoff and the Neo-Hookean law are linear in their moduli:
    ``(tr(E) I, 2 E)`` and ``(ln(J) C^-1, I - C^-1)``.  The foam's exponent
    ``beta = lambda / (2 mu)`` depends on both, so with ``j = J^(-2 beta)``

        dS/dlambda = ln(J) j C^-1,    dS/dmu = I - j (1 + 2 beta ln J) C^-1.
    """
    if law == "stvk":
        E = green_lagrange(F)
        return np.stack([np.trace(E, axis1=-2, axis2=-1)[..., None, None] * _I3, 2.0 * E])
    check_law(law)
    log_j, Ci = _log_j_and_cinv(F)
    if law == "hyperfoam":
        beta = _beta(lam, mu)
        j = np.exp(-2.0 * beta * log_j)[..., None, None]
        return np.stack([log_j[..., None, None] * j * Ci, _I3 - j * (1.0 + 2.0 * beta * log_j[..., None, None]) * Ci])
    return np.stack([log_j[..., None, None] * Ci, _I3 - Ci])


def energy_density(law: str, F, lam: float, mu: float) -> np.ndarray:
    """Stored energy per reference volume ``W(F)`` (...), J/m^3."""
    if law == "stvk":
        E = green_lagrange(F)
        return 0.5 * lam * np.trace(E, axis1=-2, axis2=-1) ** 2 + mu * np.einsum("...IJ,...IJ->...", E, E)
    check_law(law)
    log_j = np.log(_det(F))
    if law == "hyperfoam":
        beta = _beta(lam, mu)
        volumetric = -2.0 * log_j if beta == 0 else np.expm1(-2.0 * beta * log_j) / beta
        return 0.5 * mu * (np.einsum("...iI,...iI->...", F, F) - 3.0 + volumetric)
    return 0.5 * mu * (np.einsum("...iI,...iI->...", F, F) - 3.0) - mu * log_j + 0.5 * lam * log_j**2


def principal_stiffness(law: str, F, lam: float, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """Smallest eigenvalue of the Hessian of ``W`` in the principal stretches,
    and the principal stretches.

    For an isotropic law ``dW/dl_i = l_i S_i`` (``S_i`` the principal
    stresses), so

        M_ij = d^2 W / dl_i dl_j = d_ij S_i + l_i l_j D_iijj,

    ``D`` in the principal axes of ``C``.  ``M`` positive definite is the
    stability of the law along the principal stretches (Ogden, *Non-linear
    Elastic Deformations*, 1984, sect. 6.2.5); St Venant-Kirchhoff loses it in
    compression (a uniaxial bar at ``l = 1/sqrt(3)``), the Neo-Hookean law
    keeps it at every ``J > 0`` in compression.

    Returns
    -------
    min_eig : ndarray, shape (...)
        Smallest eigenvalue of ``M``, Pa.
    stretches : ndarray, shape (..., 3)
        Principal stretches ``l_i``, ascending.
    """
    S, D = stress_and_tangent(law, F, lam, mu)
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    c2, V = np.linalg.eigh(C)
    stretches = np.sqrt(np.maximum(c2, 0.0))
    S_p = np.einsum("...Ii,...IJ,...Ji->...i", V, S, V)
    D_p = np.einsum("...Ii,...Ji,...Kj,...Lj,...IJKL->...ij", V, V, V, V, D, optimize=True)
    M = D_p * stretches[..., :, None] * stretches[..., None, :]
    M[..., [0, 1, 2], [0, 1, 2]] += S_p
    return np.linalg.eigvalsh(M)[..., 0], stretches
