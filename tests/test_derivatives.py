"""Exact derivatives of rollouts (issue 30): implicit-function-theorem
sensitivities of converged steps against central differences of rollouts, on
sticking, sliding, mixed, yawed, hanging (separated), self-weighted and
compliant-gripper rollouts; and the check fails when a term of the derivative
is dropped."""

import numpy as np
import pytest

import fe_contact.fem.elasticity as elasticity
import fe_contact.stepping.gripper as gripper
import fe_contact.stepping.sensitivity as sensitivity
from fe_contact import Command, Friction, Gripper, Material, Model, NodeStatus, SolverOptions, block_mesh
from fe_contact.stepping.derivative_check import check_derivatives
from fe_contact.stepping.derivatives import OUTPUTS, rollout_derivatives

REL_TOL = 1e-6
"""Agreement of exact and central-difference derivatives (normalised, see check_derivatives)."""
DROPPED_TERM_ERROR = 1e-3
"""A derivative with a term dropped is off by at least this."""
TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14)
"""Solver tolerances far below the central differences' step (their noise is tol / step)."""
SIZE = (0.02, 0.02, 0.01)
PRESS = Command(dz=-2e-4)


def model(mu=(0.3, 0.15), angle=0.4, divisions=(2, 2, 1), density=0.0, gripper=None):
    return Model(block_mesh(SIZE, divisions), Material(2e6, 0.3, density), Friction(*mu, angle), options=TIGHT,
                 gripper=gripper or Gripper())


def statuses(result):
    return [np.bincount(r.node_status, minlength=3) for r in result.reports]


def assert_agrees(check, tol=REL_TOL):
    assert check.max_error <= tol, check.worst()


def test_sticking_rollout():
    m, cmds = model(mu=(2.0, 1.5), divisions=(3, 3, 1)), [PRESS, Command(dx=1e-5, dy=5e-6)]
    last = statuses(rollout_derivatives(m, cmds))[-1]
    assert last[NodeStatus.STICK] == m.n_contacts
    assert_agrees(check_derivatives(m, cmds))


def test_sliding_rollout():
    m, cmds = model(mu=(0.1, 0.05)), [PRESS, Command(dx=5e-4, dy=2e-4), Command(dx=4e-4)]
    result = rollout_derivatives(m, cmds)
    assert all(s[NodeStatus.SLIP] == m.n_contacts for s in statuses(result)[1:])
    assert_agrees(check_derivatives(m, cmds))


def test_mixed_stick_slip_rollout():
    m, cmds = model(divisions=(3, 3, 2)), [PRESS, Command(dx=6e-5, dy=3e-5)]
    last = statuses(rollout_derivatives(m, cmds))[-1]
    assert last[NodeStatus.STICK] > 0 and last[NodeStatus.SLIP] > 0, last
    assert_agrees(check_derivatives(m, cmds))


def test_yawed_rollout_with_self_weight():
    m = model(angle=-0.7, density=800.0)
    cmds = [PRESS, Command(dx=2e-4, dtheta=0.02), Command(dy=3e-4, dtheta=-0.01)]
    result = rollout_derivatives(m, cmds)
    assert abs(result.outputs[-1, OUTPUTS.index("lower_yaw")]) > 1e-4
    check = check_derivatives(m, cmds)
    assert_agrees(check)
    assert np.abs(result.d_parameters[:, :, result.parameters.index("density")]).max() > 0


def test_hanging_block_all_separated():
    # lifted off the floor by its upper face: every contact separated, the lower
    # face sags under the weight (its derivatives in young and density are the sag's)
    m, cmds = model(density=2000.0), [PRESS, Command(dz=4e-4), Command(dx=1e-4)]
    assert statuses(rollout_derivatives(m, cmds))[-1][NodeStatus.SEPARATED] == m.n_contacts
    assert_agrees(check_derivatives(m, cmds))


def test_compliant_gripper_rollout(monkeypatch):
    # the plate balance's own tolerance is the central differences' noise: tightened; the
    # step 3e-5 balances their h^2 error (1.8e-4, 1.6e-5, 1.7e-6 at 1e-3, 3e-4, 1e-4) and that noise
    monkeypatch.setattr(gripper, "PLATE_TOL", 1e-14)
    m = model(gripper=Gripper(2e3, 2.0))
    cmds = [PRESS, Command(dx=2e-4, dy=1e-4, dtheta=0.01)]
    result = rollout_derivatives(m, cmds)
    plate = result.outputs[-1, [OUTPUTS.index("plate_x"), OUTPUTS.index("plate_y")]]
    assert np.all(np.abs(plate - [2e-4, 1e-4]) > 1e-6)  # the plate lags the command
    check = check_derivatives(m, cmds, parameters=("angle", "stiffness_xy", "stiffness_yaw"), rel_step=3e-5)
    assert_agrees(check)


def test_derivative_rollout_is_the_plain_rollout():
    from fe_contact import run
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4, dtheta=0.01)]
    _, reports = run(m, cmds)
    result = rollout_derivatives(m, cmds)
    np.testing.assert_allclose(result.reports[-1].displacement, reports[-1].displacement, rtol=0, atol=1e-15)


def test_dropping_the_geometric_stiffness_fails(monkeypatch):
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4)]
    assert_agrees(check_derivatives(m, cmds, parameters=("young",)))
    original = elasticity._element_tangents
    monkeypatch.setattr(elasticity, "_element_tangents", lambda g, F, S, mat: original(g, F, 0.0 * S, mat))
    assert check_derivatives(m, cmds, parameters=("young",)).max_error > DROPPED_TERM_ERROR


def test_dropping_the_friction_angle_term_fails(monkeypatch):
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4)]
    monkeypatch.setattr(sensitivity, "frame_derivative", lambda angle: np.zeros((3, 3)))
    check = check_derivatives(m, cmds, parameters=("angle",))
    assert check.error[:, check.inputs.index("angle")].max() > DROPPED_TERM_ERROR


def test_dropping_the_slip_rule_friction_term_fails(monkeypatch):
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4)]
    original = sensitivity.law_jacobian

    def without_mu(*args):
        A, B, B_mu = original(*args)
        return A, B, 0.0 * B_mu

    monkeypatch.setattr(sensitivity, "law_jacobian", without_mu)
    check = check_derivatives(m, cmds, parameters=("mu_x", "mu_y"))
    assert check.error[:, check.inputs.index("mu_y")].max() > DROPPED_TERM_ERROR


def test_invalid_arguments():
    m = model()
    with pytest.raises(ValueError, match="rigid gripper"):
        rollout_derivatives(m, [PRESS], parameters=("stiffness_xy",))
    with pytest.raises(ValueError, match="unknown parameter"):
        rollout_derivatives(m, [PRESS], parameters=("mass",))


def test_continuing_from_the_press_is_the_whole_rollout():
    m, pushes = model(), [Command(dx=2e-4, dy=1e-4), Command(dx=1e-4, dtheta=0.01)]
    whole = rollout_derivatives(m, [PRESS, *pushes])
    press = rollout_derivatives(m, [PRESS])
    rest = rollout_derivatives(m, pushes, start=press)
    np.testing.assert_allclose(rest.d_parameters, whole.d_parameters[1:], rtol=1e-9,
                               atol=1e-12 * np.abs(whole.d_parameters).max())
    np.testing.assert_allclose(rest.d_commands, whole.d_commands[1:, :, 1:], rtol=1e-9,
                               atol=1e-12 * np.abs(whole.d_commands).max())


def test_superlu_tangent_gives_the_same_derivatives():
    # a mesh that is not a tensor grid is factorised by SuperLU (two solves per input instead of one pass)
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4, dtheta=0.01)]
    grid = rollout_derivatives(m, cmds).jacobian()
    lu = model()
    object.__setattr__(lu, "factor_structure", None)
    np.testing.assert_allclose(rollout_derivatives(lu, cmds).jacobian(), grid, rtol=1e-7, atol=1e-9 * np.abs(grid).max())


def test_scale_invariance_in_young():
    # weightless and displacement-driven, every force scales with E and no displacement
    # depends on it: d pose / dE = 0 and d force / dE = force / E (an exact invariant)
    m, cmds = model(), [PRESS, Command(dx=2e-4, dy=1e-4, dtheta=0.01)]
    result = rollout_derivatives(m, cmds, parameters=("young",))
    d = result.d_parameters[:, :, 0] * m.material.young
    pose, force = [OUTPUTS.index(k) for k in ("lower_x", "lower_y")], [OUTPUTS.index(k) for k in ("force_x", "force_z")]
    assert np.abs(d[:, pose]).max() <= 1e-9 * np.abs(result.outputs[:, pose]).max()
    np.testing.assert_allclose(d[:, force], result.outputs[:, force], rtol=1e-9,
                               atol=1e-12 * np.abs(result.outputs[:, force]).max())


@pytest.mark.parametrize("case", ["mixed", "yawed_weighted", "compliant"])
def test_adjoint_gradient_equals_forward_mode(case):
    from fe_contact import rollout_gradient
    if case == "mixed":
        m, cmds = model(divisions=(3, 3, 2)), [PRESS, Command(dx=6e-5, dy=3e-5), Command(dx=2e-4)]
    elif case == "yawed_weighted":
        m, cmds = model(angle=-0.7, density=800.0), [PRESS, Command(dx=2e-4, dtheta=0.02), Command(dy=3e-4)]
    else:  # the plate balance transposed too
        m = model(angle=-0.7, density=800.0, gripper=Gripper(2e3, 2.0))
        cmds = [PRESS, Command(dx=2e-4, dy=1e-4, dtheta=0.02), Command(dy=3e-4, dtheta=-0.01)]
    units = np.array([1e4, 1e4, 1e2, 1.0, 1.0, 1.0, 1e4, 1e4, 1e2])  # an objective of O(1) per output
    g = np.random.default_rng(1).normal(size=(len(cmds), len(OUTPUTS))) * units
    forward = rollout_derivatives(m, cmds)
    adjoint = rollout_gradient(m, cmds, g)
    np.testing.assert_allclose(adjoint.outputs, forward.outputs, rtol=0, atol=1e-15)
    want_c = np.einsum("ki,kijc->jc", g, forward.d_commands)
    want_p = np.einsum("ki,kip->p", g, forward.d_parameters)
    np.testing.assert_allclose(adjoint.d_commands, want_c, rtol=0, atol=1e-10 * np.abs(want_c).max())
    np.testing.assert_allclose(adjoint.d_parameters, want_p, rtol=1e-9)


def test_plate_wrench_adjoint_is_the_transpose():
    # <w, D x> = <D^T w, x> for the plate wrench's derivative and its transpose
    m = model()
    rng = np.random.default_rng(2)
    U, f = 1e-4 * rng.normal(size=(m.mesh.n_nodes, 3)), rng.normal(size=(m.mesh.upper.size, 3))
    dU, df, w = rng.normal(size=(m.mesh.n_dofs, 1)), rng.normal(size=(m.mesh.upper.size, 3, 1)), rng.normal(size=3)
    w_U, w_f = sensitivity.plate_wrench_adjoint(m, U, f, w)
    forward = float(w @ sensitivity.plate_wrench_derivative(m, U, f, dU, df)[:, 0])
    assert forward == pytest.approx(float(w_U @ dU[:, 0] + np.sum(w_f * df[:, :, 0])), rel=1e-12)


def test_isotropic_friction_has_no_axis():
    # mu_x = mu_y: the axis angle is physically absent, its derivative vanishes to rounding
    m = model(mu=(0.25, 0.25), angle=0.7)
    result = rollout_derivatives(m, [PRESS, Command(dx=3e-4, dy=-1e-4, dtheta=-0.02)])
    d_angle = result.d_parameters[:, :, result.parameters.index("angle")]
    assert np.abs(d_angle).max() <= 1e-10 * np.abs(result.d_parameters).max()


def test_steel_rectangular_block_with_27_gauss_points():
    # stiff (the central differences' noise floor is higher: their step is 1e-4, where
    # their h^2 error is 5e-7 and it was 1.6e-5 at 1e-3 and noise 3.7e-6 at 1e-5)
    m = Model(block_mesh((0.03, 0.015, 0.01), (3, 2, 2)), Material(210e9, 0.3), Friction(0.3, 0.05, 0.0),
              options=TIGHT, quadrature=3)
    cmds = [Command(dz=-1e-5), Command(dx=2e-5, dy=2e-5), Command(dx=2e-5, dy=2e-5)]
    assert_agrees(check_derivatives(m, cmds, parameters=("mu_x", "mu_y", "angle"), rel_step=1e-4))
