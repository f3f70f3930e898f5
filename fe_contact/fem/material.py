"""Isotropic hyperelastic laws as objects: stored energy ``W(F)``, stress
``S(F)``, its tangent ``dS/dE``, the stress's derivatives in the moduli, and
the stability of the law.  Each law is one class whose docstring holds its
equation; adding a law is one new class registered in :data:`LAWS_BY_NAME`
(scikit-fem's pattern: one object per law).

All laws reduce to linear elasticity with the Lame parameters ``lambda``,
``mu`` at small strain, so ``Material.young`` / ``poisson`` mean the same
thing for all.

Shapes: ``F`` is ``(..., 3, 3)``; ``S`` ``(..., 3, 3)`` Pa; ``D``
``(..., 3, 3, 3, 3)`` Pa; energies ``(...)`` J/m^3; ``lam``, ``mu`` Pa.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LAWS", "LAWS_BY_NAME", "HyperelasticLaw", "StVenantKirchhoff", "NeoHookean", "Hyperfoam", "law_of",
           "check_law", "green_lagrange", "stress", "stress_and_tangent", "stress_moduli_derivatives",
           "energy_density", "principal_stiffness"]

_I3 = np.eye(3)


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


def _det(F):
    """``det F``; NaN where it is not positive (no energy there: an inverted element)."""
    J = np.linalg.det(F)
    return np.where(J > 0, J, np.nan)


def _log_j_and_cinv(F):
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    return np.log(_det(F)), np.linalg.inv(C)


def _cinv_tangent(Ci, scale, coeff) -> np.ndarray:
    """``scale C^-1_IJ C^-1_KL + coeff (C^-1_IK C^-1_JL + C^-1_IL C^-1_JK)`` (..., 3, 3, 3, 3):
    the form of the Neo-Hookean and foam tangents; ``scale``, ``coeff`` (...)."""
    coeff = coeff[..., None, None, None, None]
    return scale[..., None, None, None, None] * np.einsum("...IJ,...KL->...IJKL", Ci, Ci) + coeff * (
        np.einsum("...IK,...JL->...IJKL", Ci, Ci) + np.einsum("...IL,...JK->...IJKL", Ci, Ci))


class HyperelasticLaw:
    """An isotropic hyperelastic law; subclasses give ``energy``, ``stress``,
    ``stress_and_tangent`` and ``moduli_derivatives``, each of ``(F, lam, mu)``."""

    name = ""

    def energy(self, F, lam: float, mu: float) -> np.ndarray:  # pragma: no cover - interface
        """Stored energy per reference volume ``W(F)`` (...), J/m^3."""
        raise NotImplementedError

    def stress(self, F, lam: float, mu: float) -> np.ndarray:  # pragma: no cover - interface
        """Second Piola-Kirchhoff stress ``S`` (..., 3, 3), Pa."""
        raise NotImplementedError

    def stress_and_tangent(self, F, lam: float, mu: float):  # pragma: no cover - interface
        """``S`` (..., 3, 3) and the material tangent ``D = dS/dE`` (..., 3, 3, 3, 3), Pa."""
        raise NotImplementedError

    def moduli_derivatives(self, F, lam: float, mu: float) -> np.ndarray:  # pragma: no cover - interface
        """``(dS/dlambda, dS/dmu)`` at fixed ``F`` (2, ..., 3, 3), dimensionless."""
        raise NotImplementedError


class StVenantKirchhoff(HyperelasticLaw):
    """St Venant-Kirchhoff, the paper's (Feng et al. 2006, eq. 5):

        W = lambda/2 tr(E)^2 + mu E:E,        S = lambda tr(E) I + 2 mu E,
        D_IJKL = lambda d_IJ d_KL + mu (d_IK d_JL + d_IL d_JK),
        (dS/dlambda, dS/dmu) = (tr(E) I, 2 E).

    It softens in compression: the uniaxial force of a bar ``E_y (l^3 - l) / 2``
    peaks at the stretch ``l = 1/sqrt(3)`` and the law is unstable beyond.
    """

    name = "stvk"

    def energy(self, F, lam, mu):
        E = green_lagrange(F)
        return 0.5 * lam * np.trace(E, axis1=-2, axis2=-1) ** 2 + mu * np.einsum("...IJ,...IJ->...", E, E)

    def stress(self, F, lam, mu):
        E = green_lagrange(F)
        return lam * np.trace(E, axis1=-2, axis2=-1)[..., None, None] * _I3 + 2.0 * mu * E

    def stress_and_tangent(self, F, lam, mu):
        S = self.stress(F, lam, mu)
        D = (lam * np.einsum("IJ,KL->IJKL", _I3, _I3)
             + mu * (np.einsum("IK,JL->IJKL", _I3, _I3) + np.einsum("IL,JK->IJKL", _I3, _I3)))
        return S, np.broadcast_to(D, S.shape[:-2] + (3, 3, 3, 3))

    def moduli_derivatives(self, F, lam, mu):
        E = green_lagrange(F)
        return np.stack([np.trace(E, axis1=-2, axis2=-1)[..., None, None] * _I3, 2.0 * E])


class NeoHookean(HyperelasticLaw):
    """Compressible Neo-Hookean, Bonet & Wood, *Nonlinear Continuum Mechanics
    for Finite Element Analysis*, 2nd ed. (2008), eq. (6.27-6.29):

        W = mu/2 (tr C - 3) - mu ln J + lambda/2 (ln J)^2,
        S = mu (I - C^-1) + lambda ln(J) C^-1,
        D_IJKL = lambda C^-1_IJ C^-1_KL + (mu - lambda ln J) (C^-1_IK C^-1_JL + C^-1_IL C^-1_JK),
        (dS/dlambda, dS/dmu) = (ln(J) C^-1, I - C^-1),

    with ``C = F^T F`` and ``J = det F``.  The volumetric term ``-mu ln J +
    lambda/2 (ln J)^2`` makes ``W -> inf`` as ``J -> 0``: no compression
    inverts it.
    """

    name = "neo_hookean"

    def energy(self, F, lam, mu):
        log_j = np.log(_det(F))
        return 0.5 * mu * (np.einsum("...iI,...iI->...", F, F) - 3.0) - mu * log_j + 0.5 * lam * log_j**2

    def stress(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        return mu * (_I3 - Ci) + lam * log_j[..., None, None] * Ci

    def stress_and_tangent(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        S = mu * (_I3 - Ci) + lam * log_j[..., None, None] * Ci
        return S, _cinv_tangent(Ci, np.full(log_j.shape, lam), mu - lam * log_j)

    def moduli_derivatives(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        return np.stack([log_j[..., None, None] * Ci, _I3 - Ci])


class Hyperfoam(HyperelasticLaw):
    """The Ogden-Hill compressible foam of Storakers (J. Mech. Phys. Solids 34
    (1986) 125-145) with one term and exponent ``alpha = 2``:

        W = mu/2 [tr C - 3 + (J^(-2 beta) - 1) / beta],    beta = nu / (1 - 2 nu) = lambda / (2 mu),
        S = mu (I - J^(-2 beta) C^-1),
        D_IJKL = mu J^(-2 beta) [2 beta C^-1_IJ C^-1_KL + C^-1_IK C^-1_JL + C^-1_IL C^-1_JK].

    With ``j = J^(-2 beta)``, ``beta`` depending on both moduli,

        dS/dlambda = ln(J) j C^-1,    dS/dmu = I - j (1 + 2 beta ln J) C^-1.

    Its Poisson's ratio is ``nu`` at every strain in uniaxial stress, ``l_t =
    l^(-nu)``; at ``nu = 0`` it is the Neo-Hookean law with ``lambda = 0``.
    """

    name = "hyperfoam"

    @staticmethod
    def beta(lam: float, mu: float) -> float:
        """The foam's ``beta = nu / (1 - 2 nu) = lambda / (2 mu)``."""
        return lam / (2.0 * mu)

    def energy(self, F, lam, mu):
        log_j, beta = np.log(_det(F)), self.beta(lam, mu)
        volumetric = -2.0 * log_j if beta == 0 else np.expm1(-2.0 * beta * log_j) / beta
        return 0.5 * mu * (np.einsum("...iI,...iI->...", F, F) - 3.0 + volumetric)

    def stress(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        return mu * (_I3 - np.exp(-2.0 * self.beta(lam, mu) * log_j)[..., None, None] * Ci)

    def stress_and_tangent(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        beta = self.beta(lam, mu)
        j = mu * np.exp(-2.0 * beta * log_j)
        return _I3 * mu - j[..., None, None] * Ci, _cinv_tangent(Ci, 2.0 * beta * j, j)

    def moduli_derivatives(self, F, lam, mu):
        log_j, Ci = _log_j_and_cinv(F)
        beta = self.beta(lam, mu)
        j = np.exp(-2.0 * beta * log_j)[..., None, None]
        return np.stack([log_j[..., None, None] * j * Ci, _I3 - j * (1.0 + 2.0 * beta * log_j[..., None, None]) * Ci])


LAWS_BY_NAME: dict[str, HyperelasticLaw] = {law.name: law for law in (StVenantKirchhoff(), NeoHookean(), Hyperfoam())}
"""Every law by its name (``Material.model``)."""
LAWS = tuple(LAWS_BY_NAME)
"""Names of the constitutive laws."""


def check_law(name) -> str:
    """``name`` if it is one of :data:`LAWS`, else ValueError naming it."""
    if not isinstance(name, str) or name not in LAWS_BY_NAME:
        raise ValueError(f"material model must be one of {tuple(LAWS_BY_NAME)}, got {name!r}")
    return name


def law_of(name) -> HyperelasticLaw:
    """The law object named ``name`` (ValueError naming it if there is none)."""
    return LAWS_BY_NAME[check_law(name)]


def stress(law: str, F, lam: float, mu: float) -> np.ndarray:
    """Second Piola-Kirchhoff stress ``S`` (..., 3, 3), Pa, of the law named ``law`` at ``F`` (..., 3, 3)."""
    return law_of(law).stress(F, lam, mu)


def stress_and_tangent(law: str, F, lam: float, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """``S`` (..., 3, 3), Pa, and the material tangent ``D = dS/dE`` (..., 3, 3, 3, 3), Pa."""
    return law_of(law).stress_and_tangent(F, lam, mu)


def stress_moduli_derivatives(law: str, F, lam: float, mu: float) -> np.ndarray:
    """``(dS/dlambda, dS/dmu)`` at fixed ``F`` (2, ..., 3, 3), dimensionless."""
    return law_of(law).moduli_derivatives(F, lam, mu)


def energy_density(law: str, F, lam: float, mu: float) -> np.ndarray:
    """Stored energy per reference volume ``W(F)`` (...), J/m^3."""
    return law_of(law).energy(F, lam, mu)


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
