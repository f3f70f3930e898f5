"""Loads beyond the paper's displacement-driven upper face: self-weight, the
compliant gripper's springs, and the regularising springs of a block held by a frictional pad.

Self-weight is the body force ``f0`` of the paper's eq. (3) with ``f0 = rho g``,
``g = (0, 0, -GRAVITY)``, integrated with the stiffness's quadrature:

    F_a = int_V N_a f0 dV = f0 sum_{e, q} N_a(xi_q) dV_eq,     (n_nodes, 3) N,

a dead load (it does not follow the deformation: its reference-configuration
integral is exact in the total Lagrangian setting).

A frictional pad (:func:`fe_contact.stepping.held.pad_loading`) leaves the
block held by contact and friction alone, so ``K_ff`` is singular in the
rigid modes of a block whose contact nodes slip or separate, and the paper's
flexibility matrix ``W = C K_ff^-1 C^T`` does not exist.  It is regularised by
a spring on every dof anchored at a configuration ``U_a``:

    f_reg = k_a (U - U_a),    k_a = beta k_shear V_a / V,   N,

``k_shear = G A / H`` the block's shear stiffness (N/m), ``V_a`` the nodal
volume, ``beta = SolverOptions.pad_regularisation``; anchored at each Newton iterate (``Loading.proximal``) the springs
exert no force at convergence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .elasticity import internal_force_and_tangent
from .element import gauss_hex, hex8_shape

GRAVITY = 9.81
"""Acceleration of gravity, m/s^2, along -z."""


def nodal_volumes(elements: np.ndarray, dvol: np.ndarray, n_nodes: int, quadrature: int) -> np.ndarray:
    """Consistent nodal volumes ``V_a = sum_{e, q} N_a(xi_q) dV_eq`` (n_nodes,), m^3.

    Parameters
    ----------
    elements : ndarray of int, shape (n_elems, 8)
    dvol : ndarray, shape (n_elems, n_qp)
        Gauss-point volume weights of :class:`~fe_contact.fem.elasticity.ElementGeometry`, m^3.
    """
    points, _ = gauss_hex(quadrature)
    weights = np.einsum("qa,eq->ea", hex8_shape(points), dvol)
    return np.bincount(elements.ravel(), weights.ravel(), minlength=n_nodes)


def body_force(volumes: np.ndarray, density: float) -> np.ndarray:
    """Self-weight as a node-major force vector (3 n_nodes,), N (eq. 3, ``f0 = rho g``)."""
    f = np.zeros((volumes.size, 3))
    f[:, 2] = -density * GRAVITY * volumes
    return f.ravel()


def diagonal_positions(indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Position in the CSR data array of each diagonal entry (n_dofs,)."""
    rows = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))
    return np.flatnonzero(indices == rows)


@dataclass(frozen=True)
class Gripper:
    """In-plane compliance of the gripper holding the upper face.

    The upper face stays one rigid plate; its vertical motion is commanded and
    its in-plane pose ``(x, y, theta)`` is tied to the commanded pose by springs:
    the force on the plate is ``k_xy (c_xy - p_xy)``, N, and the moment
    ``k_yaw (c_theta - p_theta)``, N m (``c`` commanded, ``p`` actual pose).

    Parameters
    ----------
    stiffness_xy : float
        N/m, > 0; ``inf`` (default) is the paper's displacement control.
    stiffness_yaw : float
        N m/rad, > 0; ``inf`` (default) is the paper's displacement control.
    """

    stiffness_xy: float = math.inf
    stiffness_yaw: float = math.inf

    def __post_init__(self):
        for name in ("stiffness_xy", "stiffness_yaw"):
            v = getattr(self, name)
            v = math.inf if v is None else v
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a number, got {v!r}") from None
            if math.isnan(v) or v <= 0:
                raise ValueError(f"{name} must be > 0 (inf for a rigid drive), got {v}")
            object.__setattr__(self, name, v)
        if math.isinf(self.stiffness_xy) != math.isinf(self.stiffness_yaw):
            raise ValueError("stiffness_xy and stiffness_yaw must be both finite or both inf, got "
                             f"{self.stiffness_xy} and {self.stiffness_yaw}")

    @property
    def rigid(self) -> bool:
        return math.isinf(self.stiffness_xy)

    @property
    def stiffness(self) -> np.ndarray:
        """(3,) spring stiffnesses of ``(x, y, theta)``: N/m, N/m, N m/rad."""
        return np.array([self.stiffness_xy, self.stiffness_xy, self.stiffness_yaw])


@dataclass(frozen=True)
class Loading:
    """The loads of one step besides the upper-face drive and contact.

    Attributes
    ----------
    external : ndarray, shape (n_dofs,), or None
        Applied nodal forces (self-weight, the gripper's remaining load on a
        released upper face), N.
    spring : ndarray, shape (n_dofs,), or None
        Regularising spring stiffness of each dof, N/m.
    anchor : ndarray, shape (n_dofs,), or None
        Displacement the springs are anchored at (the last converged one), m.
    diagonal : ndarray, shape (n_dofs,), or None
        CSR data positions of the stiffness's diagonal (where the springs go).
    tension_only_geometric : bool
        Tangents with the geometric stiffness of the tensile stresses only
        (:func:`~fe_contact.fem.elasticity.internal_force_and_tangent`): positive
        definite with the springs, for a free prestressed block.
    proximal : bool
        The springs are anchored at each Newton iterate (the step's loop moves
        ``anchor`` to it, :func:`fe_contact.stepping.newton.equilibrium`): they
        stiffen the tangent (a proximal-point, Levenberg-Marquardt damping of
        the correction) and exert no force at an iterate, so a converged step
        solves the unregularised problem, whatever their stiffness.
    """

    external: np.ndarray | None = None
    spring: np.ndarray | None = None
    anchor: np.ndarray | None = None
    diagonal: np.ndarray | None = None
    tension_only_geometric: bool = False
    proximal: bool = False

    def force(self, f_int: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Internal minus applied force (n_dofs,), N, at displacements ``U`` (n_nodes, 3)."""
        f = f_int if self.external is None else f_int - self.external
        if self.spring is not None:
            f = f + self.spring_force(U)
        return f

    def spring_force(self, U: np.ndarray) -> np.ndarray:
        """Regularising spring force on the block's dofs (n_dofs,), N (zero without springs)."""
        if self.spring is None:
            return np.zeros(U.size)
        return self.spring * (U.ravel() - self.anchor)

    def tangent(self, model, U: np.ndarray):
        """Internal force (n_dofs,) N (without the loads), the step's tangent
        stiffness (CSR, N/m) and the smallest ``det F``, at ``U`` (n_nodes, 3)."""
        f_int, K, min_det = internal_force_and_tangent(model.geometry, model.mesh.elements, U, model.material,
                                                       model.pattern, self.tension_only_geometric)
        return f_int, self.stiffen(K), min_det

    def stiffen(self, K):
        """Add the springs to the stiffness ``K`` (CSR of the model's pattern), in place."""
        if self.spring is not None:
            K.data[self.diagonal] += self.spring
        return K


NO_LOADING = Loading()
