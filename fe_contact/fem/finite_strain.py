"""Element forces and tangents for any law of :mod:`fe_contact.fem.material`,
on the plain hex8 (``"hex8"``) or the F-bar hex8 that does not lock (``"fbar"``).

Plain hex8: ``f_a = sum_q dV P(F_q) g_qa`` with ``P = F S`` and the tangent

    K_(a,i)(b,k) = sum_q dV g_qaJ A_iJkL g_qbL,    A_iJkL = d_ik S_JL + F_iI D_IJKL F_kK.

F-bar (de Souza Neto, Peric, Dutko, Owen, Int. J. Solids Struct. 33 (1996)
3277-3296), in the variational form of the mean dilatation (Nagtegaal, Parks,
Rice 1974): the volume change of each Gauss point is replaced by the
element's mean, ``F_bar = a F`` with ``a = (J_bar / J)^(1/3)``,
``J_bar = sum_q J_q dV_q / V_e``, so ``det F_bar = J_bar`` is one value per
element and the volumetric energy no longer locks as ``nu -> 0.5``.  The
energy ``Pi = sum_q dV W(F_bar_q)`` is differentiated exactly, so the
tangent is its Hessian and symmetric (the original F-bar's is not).  With
``h_qa = F^-T g_qa`` (spatial gradients), ``H_q = (h_qa)`` and
``H_bar = sum_q w_q H_q``, ``w_q = J_q dV_q / (J_bar V_e)``,
``b_q = H_bar - H_q = d ln(J_bar / J_q)/dU``, ``tau = P_bar : F_bar``:

    f = sum_q dV [a B^T P_bar + tau/3 b_q]
    K = sum_q dV [a^2 B^T A_bar B + (n_q b_q^T + b_q n_q^T)/3 + c_q b_q b_q^T + tau/3 d2 ln(J_bar / J_q)]

with ``n_q = a B^T (A_bar : F_bar + P_bar)``, ``c_q = (F_bar : A_bar : F_bar + tau) / 9``,
``d2 ln J_q = -X_q``, ``X_q[(a,i),(b,k)] = h_bi h_ak`` and
``d2 ln J_bar = sum_q w_q (H_q H_q^T - X_q) - H_bar H_bar^T``.  Under a
homogeneous deformation ``a = 1`` and ``b_q = 0``: both elements pass the
patch test alike.

Shapes: ``grad`` (n_elems, n_qp, 8, 3) 1/m, ``dvol`` (n_elems, n_qp) m^3,
``Ue`` element displacements (n_elems, 8, 3) m; element forces (n_elems, 8, 3)
N; element tangents (n_elems, 24, 24) N/m in the dof order ``3 a + i``.
"""

from __future__ import annotations

import math

import numpy as np

from .material import energy_density, principal_stiffness, stress, stress_and_tangent, stress_moduli_derivatives

__all__ = ["ELEMENTS", "AUTO_FBAR_POISSON", "AUTO_HEX8_POISSON", "resolve_element", "auto_fbar_weight", "auto_fbar_weight_slope", "checked_weight",
           "fbar_weight", "element_forces", "element_tangents",
           "element_force_moduli_derivatives", "element_force_weight_derivative", "element_energy", "point_deformation", "material_limit"]

ELEMENTS = ("hex8", "fbar")
"""Element formulations: the plain (fully integrated) hex8 and the F-bar hex8."""
AUTO_ELEMENT = "fbar_blend"
"""The resolved name of ``element="auto"`` between :data:`AUTO_HEX8_POISSON` and
:data:`AUTO_FBAR_POISSON`: the F-bar family member of weight ``w(nu)``."""
AUTO_HEX8_POISSON = 0.45
"""``element="auto"`` is the plain hex8 up to this Poisson's ratio (its specialised StVK
kernels): the paper's steel (nu = 0.3), the foams and the shipped nu = 0.45 scenarios keep
their results to the bit.  At 0.45 the hex8's press force on 12 x 12 x 4 is 5.8 % above
F-bar's, its discretisation error there (docs/materials.md)."""
AUTO_FBAR_POISSON = 0.48
"""``element="auto"`` is F-bar from this Poisson's ratio up (the hex8's press force is 9.5x
the converged one at nu = 0.499 on 4 x 4 x 2).  Between the two the volumetric weight
rises smoothly (:func:`auto_fbar_weight`): the answers change continuously with nu."""
_CHUNK = 1024  # elements per batch of the tangent (bounds the (e, q, 8, 27) temporaries)


def auto_fbar_weight_slope(poisson: float) -> float:
    """``d w / d nu`` of :func:`auto_fbar_weight`, 1."""
    width = AUTO_FBAR_POISSON - AUTO_HEX8_POISSON
    s = min(max((poisson - AUTO_HEX8_POISSON) / width, 0.0), 1.0)
    return 6.0 * s * (1.0 - s) / width


def auto_fbar_weight(poisson: float) -> float:
    """The F-bar weight ``w`` of ``element="auto"`` (module docstring): 0 up to
    :data:`AUTO_HEX8_POISSON`, 1 from :data:`AUTO_FBAR_POISSON`, the smoothstep
    ``3 s^2 - 2 s^3`` of ``s = (nu - nu_0) / (nu_1 - nu_0)`` between (value and slope
    continuous in nu)."""
    s = min(max((poisson - AUTO_HEX8_POISSON) / (AUTO_FBAR_POISSON - AUTO_HEX8_POISSON), 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


def resolve_element(name, poisson: float) -> str:
    """``name`` (one of :data:`ELEMENTS`, or ``"auto"``: ``"hex8"`` for ``poisson <=
    AUTO_HEX8_POISSON``, ``"fbar"`` from ``AUTO_FBAR_POISSON``, :data:`AUTO_ELEMENT` between;
    ``AUTO_ELEMENT`` itself resolves as ``"auto"``, so a model rebuilt from a resolved one at
    another nu follows the rule); ValueError for anything else."""
    if name in ("auto", AUTO_ELEMENT):
        w = auto_fbar_weight(poisson)
        return "hex8" if w == 0.0 else "fbar" if w == 1.0 else AUTO_ELEMENT
    if name not in ELEMENTS:
        raise ValueError(f"element must be 'auto' or one of {ELEMENTS}, got {name!r}")
    return name


def checked_weight(element: str, weight: float | None) -> float:
    """The F-bar weight of an element's geometry: 0 for ``"hex8"``, 1 for ``"fbar"``,
    ``weight`` in [0, 1] for :data:`AUTO_ELEMENT`; ValueError otherwise."""
    if element not in (*ELEMENTS, AUTO_ELEMENT):
        raise ValueError(f"element must be one of {ELEMENTS}, got {element!r}")
    w = {"hex8": 0.0, "fbar": 1.0}.get(element, weight)
    if w is None or not 0.0 <= float(w) <= 1.0:
        raise ValueError(f"fbar_weight must be in [0, 1] for element {element!r}, got {weight!r}")
    return float(w)


def fbar_weight(element: str, poisson: float) -> float:
    """The volumetric weight ``w`` of a resolved element name: 0 (hex8), 1 (F-bar), or
    :func:`auto_fbar_weight` for :data:`AUTO_ELEMENT`."""
    return {"hex8": 0.0, "fbar": 1.0}.get(element, None) if element != AUTO_ELEMENT else auto_fbar_weight(poisson)


def point_deformation(grad, dvol, Ue, fbar: float):
    """``F`` at the Gauss points (e, q, 3, 3), ``J = det F`` (e, q) and the
    F-bar factor ``a = (J_bar / J)^(w/3)`` (e, q) of the weight ``w = fbar`` (ones for
    the plain hex8, ``w = 0``)."""
    n_e, n_q = dvol.shape
    rows = grad.transpose(0, 2, 1, 3).reshape(n_e, 8, 3 * n_q)  # [e, a, (q, J)]
    F = np.eye(3) + (Ue.transpose(0, 2, 1) @ rows).reshape(n_e, 3, n_q, 3).transpose(0, 2, 1, 3)
    J = np.linalg.det(F)
    if not fbar:
        return F, J, np.ones_like(J)
    J_bar = np.sum(J * dvol, axis=1) / np.sum(dvol, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.cbrt(J_bar[:, None] / J)
        if fbar != 1.0:
            a = a ** float(fbar)
    return F, J, a


def _spatial_gradients(grad, F):
    """``h_qa = F^-T g_qa`` (e, q, 8, 3): ``d ln J_q / dU`` per node."""
    return grad @ np.linalg.inv(F)


def element_energy(grad, dvol, Ue, law: str, lam: float, mu: float, fbar: float) -> np.ndarray:
    """Stored energy of each element ``sum_q dV W(F_bar_q)`` (n_elems,), J."""
    F, _, a = point_deformation(grad, dvol, Ue, fbar)
    return np.sum(energy_density(law, a[..., None, None] * F, lam, mu) * dvol, axis=1)


def element_forces(grad, dvol, Ue, law: str, lam: float, mu: float, fbar: float):
    """Element internal forces (n_elems, 8, 3), N, and the smallest ``det F``
    (zero forces when it is <= 0: an inverted element has no energy)."""
    F, J, a = point_deformation(grad, dvol, Ue, fbar)
    min_det = float(J.min())
    if math.isfinite(min_det) and min_det <= 0:
        return np.zeros(Ue.shape), min_det  # inverted: no energy (ln J); min_det says so
    Fb = a[..., None, None] * F
    return _forces_of_stress(grad, dvol, F, J, a, stress(law, Fb, lam, mu), fbar), min_det


def _forces_of_stress(grad, dvol, F, J, a, S, fbar: float):
    """Element forces (n_elems, 8, 3) of the stresses ``S`` (e, q, 3, 3) at
    ``F_bar = a F`` (module docstring): linear in ``S``."""
    Fb = a[..., None, None] * F
    P = Fb @ S
    fe = _sum_grad_products(grad, P * (dvol * a)[:, :, None, None])
    if fbar:
        tau = np.einsum("...iJ,...iJ->...", P, Fb) * dvol  # (e, q), dV tau
        H = _spatial_gradients(grad, F)
        w = J * dvol / np.sum(J * dvol, axis=1, keepdims=True)
        H_bar = np.einsum("eq,eqai->eai", w, H)
        fe += (tau.sum(axis=1)[:, None, None] * H_bar - np.einsum("eq,eqai->eai", tau, H)) * (float(fbar) / 3.0)
    return fe


def element_force_moduli_derivatives(grad, dvol, Ue, law: str, lam: float, mu: float, fbar: float) -> np.ndarray:
    """Derivatives of the element forces with respect to the Lame moduli at
    fixed displacements, ``(df/dlambda, df/dmu)`` (2, n_elems, 8, 3), m^2: the
    forces are linear in ``S`` at fixed ``F`` (both elements), so they are the
    forces of ``dS/dlambda``, ``dS/dmu``
    (:func:`~fe_contact.fem.material.stress_moduli_derivatives`)."""
    F, J, a = point_deformation(grad, dvol, Ue, fbar)
    dS = stress_moduli_derivatives(law, a[..., None, None] * F, lam, mu)
    return np.stack([_forces_of_stress(grad, dvol, F, J, a, d, fbar) for d in dS])


def element_force_weight_derivative(grad, dvol, Ue, law: str, lam: float, mu: float, fbar: float) -> np.ndarray:
    """``d f / d w`` (n_elems, 8, 3), N, of the element forces at fixed displacements for
    the F-bar weight ``w``, ``a = (J_bar/J)^(w/3)``: with ``L_q = ln(J_bar / J_q)``,
    ``d a / d w = a L / 3`` and ``d F_bar / d w = L / 3 F_bar``,

        df/dw = sum_q dV [L/3 a B^T (P_bar + A_bar : F_bar) + b_q (tau/3 + w/3 L/3 (F_bar : A_bar : F_bar + tau))]

    (module docstring's symbols; ``b_q`` does not depend on ``w``)."""
    n_e, n_q = dvol.shape
    F, J, a = point_deformation(grad, dvol, Ue, fbar)
    Fb = a[..., None, None] * F
    S, D = stress_and_tangent(law, Fb.reshape(-1, 3, 3), lam, mu)
    D = np.ascontiguousarray(np.broadcast_to(D, (n_e * n_q, 3, 3, 3, 3)))
    A = _first_elasticity(Fb.reshape(-1, 3, 3), S, D, False).reshape(n_e, n_q, 9, 9)
    P = Fb @ S.reshape(n_e, n_q, 3, 3)
    AF = (A @ Fb.reshape(n_e, n_q, 9, 1)).reshape(n_e, n_q, 3, 3)
    tau = np.einsum("eqiJ,eqiJ->eq", P, Fb)
    L = np.log(np.sum(J * dvol, axis=1, keepdims=True) / np.sum(dvol, axis=1, keepdims=True) / J)
    df = _sum_grad_products(grad, (P + AF) * (dvol * a * L / 3.0)[:, :, None, None])
    H = _spatial_gradients(grad, F)
    w = J * dvol / np.sum(J * dvol, axis=1, keepdims=True)
    H_bar = np.einsum("eq,eqai->eai", w, H)
    coef = dvol * (tau / 3.0 + float(fbar) / 9.0 * L * (np.einsum("eqiJ,eqiJ->eq", AF, Fb) + tau))
    return df + coef.sum(axis=1)[:, None, None] * H_bar - np.einsum("eq,eqai->eai", coef, H)


def _sum_grad_products(grad, P):
    """``sum_(q, J) g_qaJ P_qiJ`` (e, 8, 3) as one (8 x 3q)(3q x 3) product per element."""
    n_e, n_q = P.shape[:2]
    rows = grad.transpose(0, 2, 1, 3).reshape(n_e, 8, 3 * n_q)
    return rows @ P.transpose(0, 1, 3, 2).reshape(n_e, 3 * n_q, 3)


def _outer_sum(x, y):
    """``sum_q x_q y_q^T`` (e, 24, 24) for x, y (e, q, 24)."""
    return x.transpose(0, 2, 1) @ y


def element_tangents(grad, dvol, Ue, law: str, lam: float, mu: float, fbar: float,
                     tension_only_geometric: bool = False):
    """Element forces (n_elems, 8, 3) N, tangents (n_elems, 24, 24) N/m and the
    smallest ``det F``; the tangent in batches of elements.

    ``tension_only_geometric`` builds the geometric term ``d_ik S_JL`` with the
    positive part of ``S`` (see :func:`fe_contact.fem.elasticity.internal_force_and_tangent`).
    """
    fe, min_det = element_forces(grad, dvol, Ue, law, lam, mu, fbar)
    n_elems = grad.shape[0]
    K = np.empty((n_elems, 24, 24))
    if not min_det > 0:
        K.fill(0.0 if math.isfinite(min_det) else np.nan)
        return fe, K, min_det
    for start in range(0, n_elems, _CHUNK):
        part = slice(start, start + _CHUNK)
        K[part] = _tangent_chunk(grad[part], dvol[part], Ue[part], law, lam, mu, fbar, tension_only_geometric)
    return fe, K, min_det


def _first_elasticity(Fb, S, D, tension_only: bool):
    """``A_iJkL = d_ik S_JL + F_iI D_IJKL F_kK`` (n, 3, 3, 3, 3) at points (n, 3, 3)."""
    n = Fb.shape[0]
    T = (Fb @ D.reshape(n, 3, 27)).reshape(n, 3, 3, 3, 3)  # [i, J, K, L]
    T = (T.transpose(0, 1, 2, 4, 3).reshape(n, 27, 3) @ Fb.transpose(0, 2, 1)).reshape(n, 3, 3, 3, 3)
    A = T.transpose(0, 1, 2, 4, 3).copy()  # [i, J, k, L]
    if tension_only:
        lam_s, vec = np.linalg.eigh(S)
        S = np.einsum("nij,nj,nkj->nik", vec, np.maximum(lam_s, 0.0), vec)
    for i in range(3):
        A[:, i, :, i, :] += S
    return A


def _tangent_chunk(grad, dvol, Ue, law, lam, mu, fbar, tension_only):
    n_e, n_q = dvol.shape
    F, J, a = point_deformation(grad, dvol, Ue, fbar)
    Fb = a[..., None, None] * F
    S, D = stress_and_tangent(law, Fb.reshape(-1, 3, 3), lam, mu)
    D = np.ascontiguousarray(np.broadcast_to(D, (n_e * n_q, 3, 3, 3, 3)))
    A = _first_elasticity(Fb.reshape(-1, 3, 3), S, D, tension_only).reshape(n_e, n_q, 3, 3, 3, 3)
    # sum_q dV a^2 g_aJ A_iJkL g_bL as two batched products
    Aw = (A * (dvol * a**2)[:, :, None, None, None, None]).transpose(0, 1, 3, 2, 4, 5).reshape(n_e, n_q, 3, 27)
    T = (grad @ Aw).reshape(n_e, n_q, 8, 3, 3, 3)  # [e, q, a, i, k, L]
    T = T.transpose(0, 2, 3, 4, 1, 5).reshape(n_e, 72, 3 * n_q)
    K = T @ grad.transpose(0, 1, 3, 2).reshape(n_e, 3 * n_q, 8)  # [e, (a, i, k), b]
    K = K.reshape(n_e, 8, 3, 3, 8).transpose(0, 1, 2, 4, 3).reshape(n_e, 24, 24)
    if fbar:
        K += _fbar_terms(grad, dvol, F, J, a, Fb, S.reshape(n_e, n_q, 3, 3), A, float(fbar) / 3.0)
    return K


def _fbar_terms(grad, dvol, F, J, a, Fb, S, A, k):
    """The F-bar terms of the tangent beyond ``a^2 B^T A_bar B`` (n_e, 24, 24); ``k = w / 3``
    (the module docstring's 1/3 for F-bar, ``w / 3`` for the weight ``w`` of ``a = (J_bar/J)^(w/3)``)."""
    n_e, n_q = dvol.shape
    P = Fb @ S
    tau = np.einsum("eqiJ,eqiJ->eq", P, Fb)
    AF = (A.reshape(n_e, n_q, 9, 9) @ Fb.reshape(n_e, n_q, 9, 1)).reshape(n_e, n_q, 3, 3)
    c = (np.einsum("eqiJ,eqiJ->eq", AF, Fb) + tau) * k**2 * dvol
    n = ((AF + P)[:, :, None] @ grad[..., None]).reshape(n_e, n_q, 24) * (a * dvol)[:, :, None]
    H4 = _spatial_gradients(grad, F)  # (e, q, 8, 3)
    H = H4.reshape(n_e, n_q, 24)
    w = J * dvol / np.sum(J * dvol, axis=1, keepdims=True)
    H_bar = np.einsum("eq,eqk->ek", w, H)
    b = H_bar[:, None, :] - H  # (e, q, 24)
    nb = _outer_sum(n, b) * k
    K = nb + nb.transpose(0, 2, 1) + _outer_sum(b * c[:, :, None], b)
    # tau k d2 ln(J_bar / J_q), summed: T k d2 ln J_bar + sum_q dV tau k X_q
    tw = tau * dvol * k
    T = tw.sum(axis=1)
    d2_ln_j_bar = _outer_sum(H * w[:, :, None], H) - _swap_sum(w, H4) - H_bar[:, :, None] * H_bar[:, None, :]
    return K + T[:, None, None] * d2_ln_j_bar + _swap_sum(tw, H4)


def _swap_sum(weight, H4):
    """``sum_q weight_q X_q``, ``X_q[(a,i),(b,k)] = h_bi h_ak`` (n_e, 24, 24)."""
    n_e, n_q = weight.shape
    H = H4.reshape(n_e, n_q, 24)
    Y = _outer_sum(H * weight[:, :, None], H).reshape(n_e, 8, 3, 8, 3)  # [a, k, b, i]
    return Y.transpose(0, 1, 4, 3, 2).reshape(n_e, 24, 24)


def material_limit(geometry, elements, U, material, where: str = "") -> str | None:
    """Why the material's law is past its stable range at displacement ``U``
    (n_nodes, 3), m, or None if it is not.

    The law is unstable at a Gauss point where the Hessian of ``W`` in the
    principal stretches is not positive definite
    (:func:`fe_contact.fem.material.principal_stiffness`, evaluated at
    ``F_bar`` on the F-bar element); the message names the strain reached
    there (``where``: which configuration ``U`` is) and the law to use
    instead.  ``geometry`` is an
    :class:`~fe_contact.fem.elasticity.ElementGeometry`, ``material`` a
    :class:`~fe_contact.fem.elasticity.Material`.
    """
    F, J, a = point_deformation(geometry.grad, geometry.dvol, np.asarray(U)[elements], geometry.fbar_weight)
    if not (np.all(J > 0) and np.all(np.isfinite(a))):
        return None  # inverted: not a question of the law
    min_eig, stretches = principal_stiffness(material.model, a[..., None, None] * F, material.lame_lambda,
                                             material.lame_mu)
    unstable = min_eig <= 0.0
    if not np.any(unstable):
        return None
    lo = stretches[unstable][:, 0].min()
    hi = stretches[unstable][:, 2].max()
    worst = f"a principal stretch of {lo:.3g} (compressive strain {100 * (1 - lo):.3g} %)" if lo < 1 else (
        f"a principal stretch of {hi:.3g} (tensile strain {100 * (hi - 1):.3g} %)")
    advice = ('St Venant-Kirchhoff softens in compression and is unstable beyond; use [material] model = '
              '"neo_hookean"') if material.model == "stvk" else "the strain is beyond what this law models"
    return (f"material law {material.model!r} lost stability: its tangent (d2W/dstretch2) is not positive "
            f"definite {where + ' ' if where else ''}at {int(unstable.sum())} of {unstable.size} Gauss points, reached at "
            f"{worst}; {advice}")
