"""Derivatives in the material constants for every law and element (issue 30 item 2):
the internal force's derivative in (E, nu) at fixed displacement against central
differences, then whole rollouts against central differences; the check fails when
the foam's exponent term is dropped."""

from dataclasses import replace

import numpy as np
import pytest

import fe_contact.fem.finite_strain as finite_strain
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh
from fe_contact.fem.elasticity import internal_force
from fe_contact.stepping.derivative_check import check_derivatives
from fe_contact.stepping.derivatives import applicable_parameters
from fe_contact.stepping.sensitivity import HeldLinearisation

FORCE_TOL = 1e-7
"""Exact against central differences of the internal force (steps 1e-4 E and 1e-5 in nu; their h^2
error, measured 1e-12 in E and 5e-9 to 1.2e-8 in nu)."""
REL_TOL = 1e-6
REL_STEP = 3e-5
"""Central differences' step of the rollouts (their noise over the step against their h^2 error: max errors
1.8e-6, 5.5e-7, 5.5e-7 at 1e-5, 3e-5, 1e-4 on the foam F-bar block, 2.5e-6, 6.9e-7, 3.2e-7 on StVK F-bar)."""
DROPPED_TERM_ERROR = 1e-3
TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14)
SIZE = (0.02, 0.02, 0.01)
PUSH = [Command(dz=-3e-4), Command(dx=3e-4, dy=1e-4, dtheta=0.01)]


def model(law, element, poisson=0.35, divisions=(2, 2, 1)):
    return Model(block_mesh(SIZE, divisions), Material(1e6, poisson, model=law), Friction(0.3, 0.15, 0.4),
                 element=element, options=TIGHT)


@pytest.mark.parametrize("law", ["stvk", "neo_hookean", "hyperfoam"])
@pytest.mark.parametrize("element", ["hex8", "fbar"])
def test_internal_force_derivatives_in_young_and_poisson(law, element):
    m = model(law, element, divisions=(2, 2, 2))
    U = 1e-3 * np.random.default_rng(0).normal(size=(m.mesh.n_nodes, 3))  # strains of a few 10 %
    lin = HeldLinearisation.__new__(HeldLinearisation)  # only its material forces at U
    lin.model, lin.U = m, U
    exact = lin._material_forces()
    E, nu = m.material.young, m.material.poisson

    def force(young, poisson):
        return internal_force(m.geometry, m.mesh.elements, U, replace(m.material, young=young, poisson=poisson))[0]

    for d, (h_E, h_nu) in zip(exact, [(1e-4 * E, 0.0), (0.0, 1e-5)], strict=True):
        h = h_E + h_nu
        central = (force(E + h_E, nu + h_nu) - force(E - h_E, nu - h_nu)) / (2 * h)
        assert np.abs(d - central).max() <= FORCE_TOL * np.abs(central).max()


@pytest.mark.parametrize("law, element", [("neo_hookean", "hex8"), ("hyperfoam", "fbar"), ("stvk", "fbar")])
def test_rollout_derivatives_in_the_material_constants(law, element):
    m = model(law, element)
    assert {"young", "poisson"} <= set(applicable_parameters(m))
    check = check_derivatives(m, PUSH, parameters=("mu_x", "young", "poisson"), rel_step=REL_STEP)
    assert check.max_error <= REL_TOL, check.worst()


def test_dropping_the_foams_exponent_term_fails(monkeypatch):
    m = model("hyperfoam", "hex8")
    original = finite_strain.stress_moduli_derivatives

    def without_lambda(law, F, lam, mu):
        d = original(law, F, lam, mu)
        return np.stack([0.0 * d[0], d[1]])  # the foam's beta = lambda / (2 mu): its lambda term dropped

    monkeypatch.setattr(finite_strain, "stress_moduli_derivatives", without_lambda)
    check = check_derivatives(m, PUSH, parameters=("poisson",), rel_step=REL_STEP)
    assert check.max_error > DROPPED_TERM_ERROR
