"""Total-Lagrangian St Venant-Kirchhoff hyperelasticity on hex8 elements (other
laws of :mod:`fe_contact.fem.material` and the F-bar element: :mod:`fe_contact.fem.finite_strain`).

Kinematics and material of sect. 2.1 / 6 of Feng et al. (2006):
``F = I + dU/dX``, ``E = (F^T F - I) / 2``, ``S = lambda tr(E) I + 2 mu E``,
``P = F S``. Internal forces are ``f_a = int P dN_a/dX dV`` (= dPi/dU) and the
consistent tangent is

    K_(a,i)(b,k) = int dN_a/dX_J (F_iI C_IJKL F_kK + delta_ik S_JL) dN_b/dX_L dV

with ``C_IJKL = lambda d_IJ d_KL + mu (d_IK d_JL + d_IL d_JK)``.

Array layout follows scikit-fem: element and Gauss-point axes ``(e, q)`` lead,
tensor indices trail. Index letters in the einsum strings: ``e`` element, ``q``
Gauss point, ``a``/``b`` local node, ``i``/``k`` spatial component, ``I``/``J``/
``L`` material (reference) component.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from numbers import Real

import numpy as np
import scipy.sparse as sp

from ._kernels import stvk_forces
from .assembly import SparsityPattern, assemble_matrix, assemble_vector, check_pattern
from .element import det3, gauss_hex, hex8_grad, inv3
from .finite_strain import checked_weight, element_energy, element_forces, element_tangents
from .material import check_law, green_lagrange, stress
from .mesh import BlockMesh

__all__ = ["Material", "ElementGeometry", "element_geometry", "deformation_gradient", "green_lagrange",
           "second_piola_kirchhoff", "stored_energy", "internal_force", "internal_force_and_tangent"]

_I3 = np.eye(3)


@dataclass(frozen=True)
class Material:
    """Isotropic hyperelastic material.

    Attributes
    ----------
    young : float
        Young's modulus E, Pa; finite and > 0.
    poisson : float
        Poisson's ratio nu, in (-1, 0.5).
    density : float
        Mass density rho, kg/m^3, >= 0; the block's self-weight ``rho g`` is
        the body force ``f0`` of the paper's eq. (3) (:mod:`fe_contact.fem.loads`).
        0 (default) is the paper's weightless block.
    model : str
        Constitutive law, one of :data:`fe_contact.fem.material.LAWS`:
        ``"stvk"`` (St Venant-Kirchhoff, the paper's, default),
        ``"neo_hookean"`` (compressible, rubber and foam) or ``"hyperfoam"``
        (Storakers' foam); all have the small-strain moduli ``young``, ``poisson``.
    """

    young: float
    poisson: float
    density: float = 0.0
    model: str = "stvk"

    def __post_init__(self) -> None:
        check_law(self.model)
        for name in ("young", "poisson", "density"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise ValueError(f"{name} must be a real number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if not np.isfinite(self.young) or self.young <= 0.0:
            raise ValueError(f"young must be finite and > 0, got {self.young}")
        if not -1.0 < self.poisson < 0.5:
            raise ValueError(f"poisson must lie in (-1, 0.5), got {self.poisson}")
        if not np.isfinite(self.density) or self.density < 0.0:
            raise ValueError(f"density must be finite and >= 0, got {self.density}")

    @property
    def lame_lambda(self) -> float:
        """First Lame parameter ``E nu / ((1 + nu)(1 - 2 nu))``, Pa."""
        nu = self.poisson
        return self.young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def lame_mu(self) -> float:
        """Shear modulus ``E / (2 (1 + nu))``, Pa."""
        return self.young / (2.0 * (1.0 + self.poisson))


@dataclass(frozen=True)
class ElementGeometry:
    """Reference-configuration shape-function gradients and volume weights.

    Attributes
    ----------
    grad : ndarray, shape (n_elems, n_qp, 8, 3)
        ``dN_a/dX_J`` at each Gauss point, 1/m.
    dvol : ndarray, shape (n_elems, n_qp)
        ``det(dX/dxi) * weight``, m^3.
    element, fbar_weight : str, float
        ``"hex8"`` (plain, the paper's; weight 0), ``"fbar"`` (F-bar, does not lock as
        ``nu -> 0.5``; weight 1) or ``"fbar_blend"`` (``element="auto"`` between them, its
        weight ``w`` in ``(J_bar / J)^(w/3)`` given): :func:`~fe_contact.fem.finite_strain.checked_weight`.
    """

    grad: np.ndarray
    dvol: np.ndarray
    element: str = "hex8"
    fbar_weight: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "fbar_weight", checked_weight(self.element, self.fbar_weight))
        grad = np.array(self.grad, dtype=np.float64)
        dvol = np.array(self.dvol, dtype=np.float64)
        if grad.ndim != 4 or grad.shape[2:] != (8, 3):
            raise ValueError(f"grad must have shape (n_elems, n_qp, 8, 3), got {grad.shape}")
        if dvol.shape != grad.shape[:2]:
            raise ValueError(f"dvol must have shape {grad.shape[:2]}, got {dvol.shape}")
        if not (np.all(np.isfinite(grad)) and np.all(np.isfinite(dvol))):
            raise ValueError("grad and dvol must be finite")
        if np.any(dvol <= 0.0):
            raise ValueError(f"dvol must be > 0, got min {dvol.min()}")
        grad.setflags(write=False)
        dvol.setflags(write=False)
        object.__setattr__(self, "grad", grad)
        object.__setattr__(self, "dvol", dvol)

    @property
    def n_elements(self) -> int:
        return int(self.grad.shape[0])

    # ``grad`` laid out per element as rows ``a`` and columns ``(q, J)``: Gauss-point
    # sums as batched (8 x 3 n_qp) matrix products, and the compiled force kernel's input
    @cached_property
    def grad_rows(self) -> np.ndarray:
        return np.ascontiguousarray(self.grad.transpose(0, 2, 1, 3).reshape(self.n_elements, 8, -1))

    @property
    def n_qp(self) -> int:
        return int(self.grad.shape[1])


def element_geometry(mesh: BlockMesh, quadrature: int = 3, element: str = "hex8",
                     fbar_weight: float | None = None) -> ElementGeometry:
    """Precompute ``dN/dX`` and ``dV`` at the Gauss points of every element.

    Parameters
    ----------
    mesh : BlockMesh
    quadrature : int, default 3
        Gauss points per direction (3 -> 27 points, as in the paper; 2 -> 8).
    element, fbar_weight : str, default "hex8"; float, optional
        Formulation and the blend's weight (:class:`ElementGeometry`).

    Returns
    -------
    ElementGeometry

    Raises
    ------
    ValueError
        If ``quadrature`` is invalid or an element has a non-positive Jacobian.
    """
    if not isinstance(mesh, BlockMesh):
        raise ValueError(f"mesh must be a BlockMesh, got {type(mesh).__name__}")
    points, weights = gauss_hex(quadrature)
    dndxi = hex8_grad(points)  # (q, a, d)
    coords = mesh.nodes[mesh.elements]  # (e, a, I)
    # dX_I/dxi_d as one matrix product (e I, a) x (a, q d): 30x faster than the einsum
    jac = np.tensordot(coords, dndxi, axes=([1], [1])).transpose(0, 2, 1, 3)
    det = det3(jac)
    if np.any(det <= 0.0):
        bad = int(np.argmin(det.min(axis=1)))
        raise ValueError(f"element {bad} has non-positive Jacobian determinant {det.min()}")
    inv = inv3(jac, det)  # dxi_d/dX_I, indexed [d, I]
    grad = np.einsum("qad,eqdI->eqaI", dndxi, inv, optimize=True)  # BLAS: 15x faster than unoptimised
    return ElementGeometry(grad=grad, dvol=det * weights[None, :], element=element, fbar_weight=fbar_weight)


def _check_state(geometry: ElementGeometry, elements, U, material: Material):
    if not isinstance(geometry, ElementGeometry):
        raise ValueError(f"geometry must be an ElementGeometry, got {type(geometry).__name__}")
    if not isinstance(material, Material):
        raise ValueError(f"material must be a Material, got {type(material).__name__}")
    elements = np.asarray(elements)
    if not np.issubdtype(elements.dtype, np.integer):
        raise ValueError(f"elements must be an integer array, got dtype {elements.dtype}")
    if elements.shape != (geometry.n_elements, 8):
        raise ValueError(
            f"elements must have shape ({geometry.n_elements}, 8) to match geometry, "
            f"got {elements.shape}"
        )
    U = np.asarray(U, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] != 3:
        raise ValueError(f"U must have shape (n_nodes, 3), got {U.shape}")
    if elements.min() < 0 or elements.max() >= U.shape[0]:
        raise ValueError(
            f"elements reference node {elements.max()} but U has only {U.shape[0]} rows"
        )
    if not np.all(np.isfinite(U)):
        raise ValueError("U must be finite")
    return elements, U


def deformation_gradient(geometry: ElementGeometry, elements, U) -> np.ndarray:
    """``F = I + dU/dX`` at every Gauss point.

    Parameters
    ----------
    geometry : ElementGeometry
    elements : ndarray of int, shape (n_elems, 8)
    U : ndarray, shape (n_nodes, 3)
        Total nodal displacements, m.

    Returns
    -------
    ndarray, shape (n_elems, n_qp, 3, 3)
    """
    return _I3 + _displacement_gradient(geometry, elements, U)


def _displacement_gradient(geometry: ElementGeometry, elements, U) -> np.ndarray:
    n_elems, n_qp = geometry.dvol.shape
    # H[e, q, i, J] = sum_a U[e_a, i] dN_a/dX_J, one (3 x 8)(8 x 3 n_qp) product per element
    H = np.matmul(U[elements].transpose(0, 2, 1), geometry.grad_rows)
    return H.reshape(n_elems, 3, n_qp, 3).transpose(0, 2, 1, 3)


def second_piola_kirchhoff(E, material: Material) -> np.ndarray:
    """Second Piola-Kirchhoff stress of the material's law at ``E``, Pa
    (St Venant-Kirchhoff: ``S = lambda tr(E) I + 2 mu E``; the others
    through :func:`fe_contact.fem.material.stress` at ``F = chol(I + 2E)^T``,
    their ``S`` depending on ``C = I + 2 E`` only).

    Parameters
    ----------
    E : array_like, shape (..., 3, 3)
        Green-Lagrange strains.
    material : Material

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    if not isinstance(material, Material):
        raise ValueError(f"material must be a Material, got {type(material).__name__}")
    E = np.asarray(E, dtype=np.float64)
    if E.shape[-2:] != (3, 3):
        raise ValueError(f"E must have shape (..., 3, 3), got {E.shape}")
    if material.model != "stvk":
        F = np.swapaxes(np.linalg.cholesky(_I3 + 2.0 * E), -1, -2)
        return stress(material.model, F, material.lame_lambda, material.lame_mu)
    trace = np.trace(E, axis1=-2, axis2=-1)
    return material.lame_lambda * trace[..., None, None] * _I3 + 2.0 * material.lame_mu * E


def _strain_state(geometry, elements, U):
    """``H = F - I`` and the Green-Lagrange ``E`` at every Gauss point,
    component-major: shape ``(3, 3, n_elems * n_qp)``, points in ``(e, q)`` order.
    The hot path of every Newton iteration: each tensor component is one long
    vector, so the algebra is a few dozen vectorised operations instead of
    batched 3x3 products."""
    n_elems, n_qp = geometry.dvol.shape
    Hq = _displacement_gradient(geometry, elements, U)  # (e, q, i, J) view
    H = np.ascontiguousarray(Hq.transpose(2, 3, 0, 1)).reshape(3, 3, n_elems * n_qp)
    E = np.empty_like(H)
    for i in range(3):
        for j in range(i, 3):
            # green_lagrange(I + H), without forming I + H first
            e_ij = H[i, j] + H[j, i] + H[0, i] * H[0, j] + H[1, i] * H[1, j] + H[2, i] * H[2, j]
            e_ij *= 0.5
            E[i, j] = e_ij
            E[j, i] = e_ij
    return H, E


def _stress_state(geometry, elements, U, material):
    """``H = F - I`` and St Venant-Kirchhoff's ``S = lambda tr(E) I + 2 mu E`` at
    every Gauss point, component-major (:func:`_strain_state`)."""
    H, E = _strain_state(geometry, elements, U)
    trace = E[0, 0] + E[1, 1] + E[2, 2]
    S = E
    S *= 2.0 * material.lame_mu  # E is not needed after: S takes its buffer
    for k in range(3):
        S[k, k] += material.lame_lambda * trace
    return H, S


def stored_energy(geometry: ElementGeometry, elements, U, material: Material) -> float:
    """Total strain energy ``int W dV``, J (St Venant-Kirchhoff:
    ``W = lambda/2 tr(E)^2 + mu E:E``; the material's law on its element,
    :mod:`fe_contact.fem.finite_strain`).

    Parameters
    ----------
    geometry : ElementGeometry
    elements : ndarray of int, shape (n_elems, 8)
    U : ndarray, shape (n_nodes, 3)
        Total nodal displacements, m.
    material : Material

    Returns
    -------
    float
    """
    elements, U = _check_state(geometry, elements, U, material)
    if not _plain_stvk(geometry, material):
        return float(element_energy(geometry.grad, geometry.dvol, U[elements], material.model,
                                    material.lame_lambda, material.lame_mu, geometry.fbar_weight).sum())
    _, E = _strain_state(geometry, elements, U)  # component-major, points in (e, q) order
    E = E.reshape(9, -1)
    trace = E[0] + E[4] + E[8]
    density = 0.5 * material.lame_lambda * trace**2 + material.lame_mu * np.einsum("cn,cn->n", E, E)
    return float(np.sum(density * geometry.dvol.ravel()))


def internal_force(
    geometry: ElementGeometry, elements, U, material: Material
) -> tuple[np.ndarray, float]:
    """Assembled internal force vector ``f_int = int B(U)^T S dV = dPi/dU``.

    Parameters
    ----------
    geometry : ElementGeometry
        From :func:`element_geometry` for the same mesh.
    elements : ndarray of int, shape (n_elems, 8)
    U : ndarray, shape (n_nodes, 3)
        Total nodal displacements, m.
    material : Material

    Returns
    -------
    f_int : ndarray, shape (3 * n_nodes,)
        Node-major internal forces, N.
    min_det_f : float
        Smallest ``det F`` over all Gauss points; ``<= 0`` means the
        displacement inverts an element and the result is not physical.

    Raises
    ------
    ValueError
        If shapes are inconsistent or ``U`` is not finite.
    """
    elements, U = _check_state(geometry, elements, U, material)
    if not _plain_stvk(geometry, material):
        fe, min_det = element_forces(geometry.grad, geometry.dvol, U[elements], material.model,
                                     material.lame_lambda, material.lame_mu, geometry.fbar_weight)
        return assemble_vector(elements, fe, U.shape[0]), min_det
    return _stvk_force(geometry, elements, U, material)


def _plain_stvk(geometry: ElementGeometry, material: Material) -> bool:
    """The paper's St Venant-Kirchhoff hex8, computed by this module's own
    (faster) kernels; other laws and elements by :mod:`fe_contact.fem.finite_strain`."""
    return material.model == "stvk" and geometry.fbar_weight == 0.0


def _stvk_force(geometry: ElementGeometry, elements: np.ndarray, U: np.ndarray,
                material: Material) -> tuple[np.ndarray, float]:
    """St Venant-Kirchhoff hex8 internal force (n_dofs,), N, and the smallest ``det F``:
    the compiled kernel :func:`fe_contact.fem._kernels.stvk_forces` (one pass over the
    Gauss points, 1.9 ms on the paper's 20 x 20 x 5 mesh with 27 points an element,
    where the same sums as batched numpy products took 6.1 ms)."""
    f = np.zeros(U.size)
    min_det = stvk_forces(geometry.grad_rows, geometry.dvol, np.ascontiguousarray(elements, dtype=np.int64),
                          np.ascontiguousarray(U, dtype=np.float64), material.lame_lambda, material.lame_mu, f)
    return f, float(min_det)


_TANGENT_CHUNK = 64
"""Elements per batch of :func:`_element_tangents`: its temporaries (about 60 kB an element
with 27 Gauss points) stay in 4 MB, where all at once they were 0.1 GB of fresh pages on the
paper's mesh, whose faults sometimes cost 0.2 s of system time instead of 0.02 s.  The
paper's tangent: 0.076-0.22 s on its first call -> 0.055-0.066 s (the same numbers to the
bit; fresh processes, quiet machine)."""


def _element_tangents(geometry: ElementGeometry, F, S, material: Material) -> np.ndarray:
    """Element tangent matrices, shape (n_elems, 24, 24), dof order ``3*a + i``, a batch
    of :data:`_TANGENT_CHUNK` elements at a time (:func:`_element_tangents_of`)."""
    K = np.empty((geometry.dvol.shape[0], 24, 24))
    for start in range(0, K.shape[0], _TANGENT_CHUNK):
        part = slice(start, start + _TANGENT_CHUNK)
        K[part] = _element_tangents_of(geometry.grad[part], geometry.dvol[part], F[part], S[part], material)
    return K


def _element_tangents_of(grad, dvol, F, S, material: Material) -> np.ndarray:
    """Element tangent matrices of the elements of ``grad`` (n, n_qp, 8, 3), ``dvol``
    (n, n_qp), ``F`` and ``S`` (n, n_qp, 3, 3): shape (n, 24, 24), dof order ``3*a + i``.

    For StVK ``F_iI C_IJKL F_kK = lambda F_iJ F_kL + mu (b_ik d_JL + F_iL F_kJ)``
    with ``b = F F^T``, so with ``g_a = dN_a/dX`` and ``G_ai = F_iJ g_aJ``

        K_aibk = sum_q dV [lambda G_ai G_bk + mu G_ak G_bi
                           + mu b_ik (g_a . g_b) + d_ik (g_a . S g_b)].

    Each term is a contraction over the Gauss points done as a batched matrix
    product (BLAS) rather than a generic einsum, which is several times faster.
    """
    n_elems, n_qp = dvol.shape
    lam, mu = material.lame_lambda, material.lame_mu

    G = np.einsum("eqiJ,eqaJ->eqai", F, grad).reshape(n_elems, n_qp, 24)
    GW = G * dvol[:, :, None]
    # X[e, (a,i), (b,k)] = sum_q dV G_ai G_bk
    X = np.matmul(GW.transpose(0, 2, 1), G).reshape(n_elems, 8, 3, 8, 3)
    K = lam * X + mu * X.transpose(0, 1, 4, 3, 2)

    # mu b_ik (g_a . g_b): contraction over q of an (a,b) and an (i,k) factor
    gg = np.matmul(grad, grad.transpose(0, 1, 3, 2)) * dvol[:, :, None, None]  # (e,q,a,b)
    b = np.matmul(F, F.transpose(0, 1, 3, 2))  # (e,q,i,k)
    Y = np.matmul(
        gg.reshape(n_elems, n_qp, 64).transpose(0, 2, 1), b.reshape(n_elems, n_qp, 9)
    ).reshape(n_elems, 8, 8, 3, 3)
    K += mu * Y.transpose(0, 1, 3, 2, 4)

    # geometric stiffness d_ik (g_a S g_b)
    gS = np.matmul(grad, S) * dvol[:, :, None, None]  # (e,q,a,J)
    geo = np.matmul(
        gS.transpose(0, 2, 1, 3).reshape(n_elems, 8, 3 * n_qp),
        grad.transpose(0, 1, 3, 2).reshape(n_elems, 3 * n_qp, 8),
    )  # (e,a,b)
    for i in range(3):
        K[:, :, i, :, i] += geo
    return K.reshape(n_elems, 24, 24)


def internal_force_and_tangent(
    geometry: ElementGeometry,
    elements,
    U,
    material: Material,
    pattern: SparsityPattern,
    tension_only_geometric: bool = False,
) -> tuple[np.ndarray, sp.csr_matrix, float]:
    """Internal forces and the consistent tangent stiffness ``d f_int / dU``.

    Parameters
    ----------
    geometry : ElementGeometry
    elements : ndarray of int, shape (n_elems, 8)
    U : ndarray, shape (n_nodes, 3)
        Total nodal displacements, m.
    material : Material
    pattern : SparsityPattern
        From :func:`fe_contact.fem.assembly.sparsity_pattern` for ``elements``.
    tension_only_geometric : bool
        Build the geometric stiffness with the positive part of ``S`` only
        (per Gauss point, ``S_+ = V max(Lambda, 0) V^T``): a positive
        semi-definite tangent for a free, prestressed block whose consistent
        tangent is indefinite in its rigid rotations (a block held by a frictional pad,
        :func:`fe_contact.stepping.held.pad_loading`).  Not the consistent tangent: Newton
        converges linearly with it, to the same solution.

    Returns
    -------
    f_int : ndarray, shape (3 * n_nodes,)
        Internal forces, N.
    K : scipy.sparse.csr_matrix, shape (3 * n_nodes, 3 * n_nodes)
        Material + geometric stiffness, symmetric, N/m.
    min_det_f : float
        Smallest ``det F`` over all Gauss points.

    Raises
    ------
    ValueError
        If shapes are inconsistent or the pattern was built for other elements.
    """
    elements, U = _check_state(geometry, elements, U, material)
    check_pattern(pattern, elements, U.shape[0])
    if not _plain_stvk(geometry, material):
        fe, Ke, min_det = element_tangents(geometry.grad, geometry.dvol, U[elements], material.model,
                                           material.lame_lambda, material.lame_mu, geometry.fbar_weight,
                                           tension_only_geometric)
        return assemble_vector(elements, fe, U.shape[0]), assemble_matrix(pattern, Ke), min_det
    f_int, min_det = _stvk_force(geometry, elements, U, material)
    H, S = _stress_state(geometry, elements, U, material)
    n_elems, n_qp = geometry.dvol.shape
    # component-major (3, 3, e q) -> (e, q, 3, 3)
    H_points, S_points = (np.ascontiguousarray(A.reshape(3, 3, n_elems, n_qp).transpose(2, 3, 0, 1)) for A in (H, S))
    if tension_only_geometric:
        lam, vec = np.linalg.eigh(S_points)
        S_points = np.einsum("eqij,eqj,eqkj->eqik", vec, np.maximum(lam, 0.0), vec)
    K = assemble_matrix(pattern, _element_tangents(geometry, _I3 + H_points, S_points, material))
    return f_int, K, min_det
