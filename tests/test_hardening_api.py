"""Issue 43: the Python API a plugin user calls checks its arguments at the public face
(type, range, finiteness, real numbers), and a friction coefficient outside fe_contact's
stated range (0 to MU_MAX) is refused instead of a "converged" step whose
contact law does not hold."""

import math

import numpy as np
import pytest

from fe_contact import MU_MAX, Command, Friction, block_mesh, build_model, initial_state, run
from fe_contact import project_elliptic_cone
from fe_contact.contact.local_solver import solve_local


@pytest.mark.parametrize("mu_x, mu_y", [(1e200, 0.1), (1e-300, 1e300), (1e300, 1e300), (1e7, 1e7),
                                        (math.nextafter(MU_MAX, math.inf), 0.1), (-0.0001, 0.1), (math.nan, 0.1)])
def test_a_coefficient_outside_the_stated_range_is_refused_everywhere(mu_x, mu_y):
    tau = np.array([1.0, 0.5, -0.3])
    with pytest.raises(ValueError, match=r"must be finite, >= 0 and <= 1000"):
        project_elliptic_cone(tau, mu_x, mu_y)
    with pytest.raises(ValueError, match=r"must be finite, >= 0 and <= 1000"):
        solve_local(np.eye(3), -tau, mu_x, mu_y, method="newton")
    with pytest.raises(ValueError, match=r"must be finite" + ("" if math.isnan(mu_x) else ", >= 0 and <= 1000")):
        Friction(mu_x, mu_y)


@pytest.mark.parametrize("mu", [0.0, 1e-300, MU_MAX])
def test_the_projection_at_the_bounds_is_finite_and_in_the_cone(mu):
    tau = np.array([[1.0, 3.0, -2.0], [-1.0, 0.5, 0.1], [2.0, 1e-3, 1e-3]])
    r = project_elliptic_cone(tau, mu, 0.3)
    assert np.all(np.isfinite(r))
    tx = np.where(mu > 0, r[:, 1] / max(mu, 1e-300), 0.0)
    assert np.all(np.hypot(tx, r[:, 2] / 0.3) <= r[:, 0] * (1 + 1e-12) + 1e-15)
    assert np.all(np.sum((tau - r) * r, axis=1) <= 1e-9 * np.linalg.norm(tau, axis=1))  # tau - r normal to the cone at r


def test_a_complex_point_or_coefficient_is_refused_not_truncated():
    with pytest.raises(ValueError, match="tau must be real"):
        project_elliptic_cone(np.array([1.0, 0.5j, 0.0]), 0.3, 0.3)
    with pytest.raises(ValueError, match="mu_x must be real"):
        project_elliptic_cone(np.array([1.0, 0.5, 0.0]), 0.3 + 0.1j, 0.3)


@pytest.mark.parametrize("max_iter", ["5", 1.5, 5.0, True, 0])
def test_solve_local_takes_an_integer_iteration_limit_only(max_iter):
    with pytest.raises(ValueError, match="max_iter must be an integer >= 1"):
        solve_local(np.eye(3), np.array([-1.0, 0.0, 0.0]), 0.3, 0.3, max_iter=max_iter)
    assert solve_local(np.eye(3), np.array([-1.0, 0.0, 0.0]), 0.3, 0.3, max_iter=np.int64(5)).iterations >= 0


def test_a_mesh_too_large_for_memory_is_a_value_error_naming_its_divisions():
    with pytest.raises(ValueError, match=r"divisions \(1000000, 1000000, 1000000\) make 1e\+18 elements"):
        block_mesh((1.0, 1.0, 1.0), (10**6,) * 3)


def test_a_press_at_the_largest_coefficient_holds_the_contact_law():
    """At ``mu = MU_MAX`` the press converges with the lower face on the plane: no node
    inside it (the 1e7 case was "converged" 84.5 um inside), every node in contact."""
    model = build_model((0.02, 0.02, 0.01), (2, 2, 1), 210e9, 0.3, MU_MAX, MU_MAX, quadrature=2)
    _, reports = run(model, [Command(dz=-1e-4), Command(dx=1e-5)], initial_state(model))
    for rep in reports:
        assert rep.converged
        assert rep.gap.min() >= -1e-9, rep.gap.min()  # m: Signorini, no penetration
        assert rep.normal_force > 0
