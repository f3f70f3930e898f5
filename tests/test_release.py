"""Self-weight, the compliant gripper and the release of the block (issue 19),
on a coarse rubber block (40 x 30 x 20 mm, 4 x 3 x 2 elements)."""

import math

import numpy as np
import pytest

from fe_contact import (GRAVITY, Command, Friction, Gripper, Material, Model, Release, SolverOptions, block_mesh,
                        initial_state, run, run_release)
from fe_contact.fem.elasticity import internal_force
from fe_contact.stepping.measure import plate_wrench

WEIGHT_RTOL = 1e-8  # issue: normal forces sum to rho g V to 1e-8 relative
REST_FORCE_RTOL = 1e-8  # issue: in-plane contact forces at rest <= 1e-8 of the weight
STRESS_FREE_RTOL = 1e-9  # issue: strain energy after a lift <= 1e-9 of its loaded value
REST_POSE_RTOL = 1e-6  # issue: rest pose = commanded rigid motion to 1e-6 of the lag
SPRING_RTOL = 1e-9  # issue: gripper spring force = upper-face reaction
STIFF_GRIPPER_RTOL = 1e-6  # issue: a stiff gripper reproduces the rigid drive, relative to the lag
EQUILIBRIUM_TOL = 1e-8  # step reports' equilibrium error with weight
CONTRACTION = 0.5  # open release: each refinement moves the rest pose at most half as much as the previous
REFINED_CHANGE = 0.05  # ... and the last one by at most this fraction of the lag

SIZE = (0.04, 0.03, 0.02)
DIVISIONS = (4, 3, 2)
RUBBER = dict(young=2e6, poisson=0.45)
DENSITY = 1000.0
PRESS = Command(dz=-4e-4)
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
TARGET = (3e-3, 1e-3, math.radians(5.0))  # 5 pushes


def model(density=0.0, gripper=None, beta=None, quadrature=3):
    options = SolverOptions() if beta is None else SolverOptions(release_stiffness=beta)
    return Model(block_mesh(SIZE, DIVISIONS), Material(**RUBBER, density=density),
                 Friction(0.6, 0.2, math.radians(20.0)), options=options, gripper=gripper or Gripper(),
                 quadrature=quadrature)


def loaded(m, pushes=5, push=PUSH):
    state, reports = run(m, [PRESS] + [push] * pushes)
    assert all(r.converged for r in reports)
    return state, reports[-1]


def test_body_force_is_the_weight():
    m = model(DENSITY)
    assert m.body_force.reshape(-1, 3)[:, :2].sum() == 0.0
    assert -m.body_force.sum() == pytest.approx(DENSITY * GRAVITY * np.prod(SIZE), rel=1e-12)
    assert model().body_force is None and model().weight == 0.0


def test_weight_alone_rests_on_the_contact():
    m = model(DENSITY)
    state, reports = run_release(m, initial_state(m), Release("open", 1))
    rest = reports[-1]
    assert rest.converged and rest.grip == 0.0
    assert rest.normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)
    assert np.linalg.norm(rest.tangential_force) <= REST_FORCE_RTOL * m.weight
    assert rest.equilibrium_error <= EQUILIBRIUM_TOL


def test_held_steps_with_weight_are_in_equilibrium():
    m = model(DENSITY)
    _, reports = run(m, [PRESS, PUSH])
    for r in reports:
        assert r.converged and r.equilibrium_error <= EQUILIBRIUM_TOL
        # the drive, the contact and the weight balance
        assert abs(r.upper_force[2] + r.normal_force - m.weight) <= EQUILIBRIUM_TOL * r.normal_force


@pytest.mark.parametrize("gripper", [None, "compliant"])
def test_lift_leaves_the_block_stress_free_under_the_upper_face(gripper):
    m0 = model()
    k = m0.shear_stiffness
    m = model(gripper=Gripper(k, k * (SIZE[0] ** 2 + SIZE[1] ** 2) / 12) if gripper else None)
    state, last = loaded(m)
    _, reports = run_release(m, state, Release("lift", 5), last)
    rest = reports[-1]
    assert all(r.converged for r in reports)
    assert rest.strain_energy <= STRESS_FREE_RTOL * last.strain_energy
    lag = np.linalg.norm(last.lag)
    assert np.linalg.norm(rest.lower_centroid[:2] - TARGET[:2]) <= REST_POSE_RTOL * lag
    assert abs(rest.lower_yaw - TARGET[2]) * max(SIZE) <= REST_POSE_RTOL * lag


def test_open_release_rests_on_friction_and_weight():
    m = model(DENSITY)
    state, last = loaded(m)
    _, reports = run_release(m, state, Release("open", 5), last)
    rest = reports[-1]
    assert all(r.converged for r in reports)
    assert rest.regularisation_force <= 1e-10 * m.weight
    assert np.linalg.norm(rest.tangential_force) <= REST_FORCE_RTOL * m.weight
    assert rest.normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)
    assert np.linalg.norm(rest.upper_force) == 0.0


def test_open_release_converges_as_it_is_refined():
    """The sliding block (5 pushes) released in 8, 16, 32 steps with the
    regularisation 0.1, and in 16 steps with 0.2, 0.1, 0.05: the rest pose
    moves less at each refinement, and the last refinements move it by a
    small fraction of the lag."""
    rest = {}
    for beta in (0.2, 0.1, 0.05):
        m = model(DENSITY, beta=beta, quadrature=2)
        state, last = loaded(m)
        for n in (8, 16, 32) if beta == 0.1 else (16,):
            _, reports = run_release(m, state, Release("open", n), last)
            assert reports[-1].converged
            rest[beta, n] = reports[-1].lower_centroid[:2]
    lag = np.linalg.norm(last.lag)
    by_steps = [np.linalg.norm(rest[0.1, b] - rest[0.1, a]) / lag for a, b in ((8, 16), (16, 32))]
    by_beta = [np.linalg.norm(rest[b, 16] - rest[a, 16]) / lag for a, b in ((0.2, 0.1), (0.1, 0.05))]
    print("refinement by steps", by_steps, "by regularisation", by_beta)
    assert by_steps[1] < CONTRACTION * by_steps[0] and by_beta[1] < CONTRACTION * by_beta[0]
    assert max(by_steps[1], by_beta[1]) <= REFINED_CHANGE


def test_compliant_gripper_spring_balances_the_upper_face():
    m0 = model()
    k = m0.shear_stiffness
    m = model(gripper=Gripper(k, k * 1e-4))
    _, reports = run(m, [PRESS, PUSH, PUSH])
    for r in reports:
        assert r.converged
        f_int, _ = internal_force(m.geometry, m.mesh.elements, r.displacement, m.material)
        reaction = plate_wrench(m, r.displacement, f_int.reshape(-1, 3)[m.mesh.upper])
        scale = np.abs(reaction).max() + abs(r.upper_force[2])
        np.testing.assert_allclose(r.gripper_force, reaction, rtol=0, atol=SPRING_RTOL * scale)
    assert np.linalg.norm(reports[-1].plate[:2] - [1.2e-3, 4e-4]) > 1e-5  # the plate lags its command


def test_stiff_gripper_is_the_rigid_drive():
    rigid = model()
    k = 1e6 * rigid.shear_stiffness
    stiff = model(gripper=Gripper(k, k * (SIZE[0] ** 2 + SIZE[1] ** 2) / 12))
    _, a = loaded(rigid)
    _, b = loaded(stiff)
    assert np.linalg.norm(a.lower_centroid - b.lower_centroid) <= STIFF_GRIPPER_RTOL * np.linalg.norm(a.lag)


@pytest.mark.parametrize("make, match", [
    (lambda: Material(2e6, 0.45, density=-1.0), "density"),
    (lambda: Gripper(-1.0, 1.0), "stiffness_xy"),
    (lambda: Gripper(1.0, 0.0), "stiffness_yaw"),
    (lambda: Release("lift", 0), "steps"),
    (lambda: Release("drop", 3), "mode"),
    (lambda: Command(dx=1e-3, open=0.5), "open"),
])
def test_bad_input_names_the_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_open_release_needs_weight():
    m = model()
    with pytest.raises(ValueError, match="density"):
        run_release(m, initial_state(m), Release("open", 2))
