"""An independent reference for the press of a nearly incompressible block:
linear elasticity in mixed displacement / pressure form with Taylor-Hood
tetrahedra (P2 displacements, P1 pressure, inf-sup stable, no locking as
nu -> 0.5), assembled by scikit-fem (an optional test dependency).

    int 2 mu eps(u):eps(v) + p div v = 0,    int q div u - p q / lambda = 0,

on the quarter block ``[0, lx/2] x [0, ly/2] x [0, lz]`` (symmetry planes
``u_x = 0`` at x = 0, ``u_y = 0`` at y = 0), floor ``u_z = 0`` with free
sliding (a frictionless floor in compression) or ``u = 0`` (``bonded``: a
floor that does not let the block slip), upper face bonded and moved
by ``(0, 0, dz)``.  Returns the total normal force, N (the full block's).
Nothing here is shared with fe_contact.
"""

from __future__ import annotations

import numpy as np


def press_force(young: float, poisson: float, size, dz: float, n: int, bonded: bool = False) -> float:
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve
    from skfem import Basis, BilinearForm, ElementTetP1, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.helpers import ddot, div, sym_grad

    lx, ly, lz = (float(s) for s in size)
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = young / (2 * (1 + poisson))
    nz = max(1, n // 2) * 2  # the quarter's height is the full height: twice the in-plane density
    mesh = MeshTet.init_tensor(np.linspace(0, lx / 2, n + 1), np.linspace(0, ly / 2, n + 1),
                               np.linspace(0, lz, nz + 1))
    ub = Basis(mesh, ElementVector(ElementTetP2()))
    pb = ub.with_element(ElementTetP1())

    @BilinearForm
    def a(u, v, w):
        return 2 * mu * ddot(sym_grad(u), sym_grad(v))

    @BilinearForm
    def b(u, q, w):
        return div(u) * q

    @BilinearForm
    def c(p, q, w):
        return p * q / lam

    A, B, C = asm(a, ub), asm(b, ub, pb), asm(c, pb)
    K = sp.bmat([[A, B.T], [B, -C]], format="csr")
    x = np.zeros(K.shape[0])
    tol = 1e-12
    def on(axis, value, component):
        return ub.get_dofs(lambda p: np.abs(p[axis] - value) < tol).all([component])

    top_z = on(2, lz, "u^3")
    x[top_z] = dz
    D = np.unique(np.concatenate([on(2, lz, "u^1"), on(2, lz, "u^2"), top_z, on(0, 0.0, "u^1"),
                                  on(1, 0.0, "u^2"), on(2, 0.0, "u^3"),
                                  *([on(2, 0.0, "u^1"), on(2, 0.0, "u^2")] if bonded else [])]))
    free = np.setdiff1d(np.arange(K.shape[0]), D)
    x[free] = spsolve(K[free][:, free].tocsc(), -K[free][:, D] @ x[D])
    reaction = K @ x
    return -4.0 * float(reaction[top_z].sum())  # force on the block's top, compressive > 0
