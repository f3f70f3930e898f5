"""Self-weight, the compliant gripper and the bonded lift of the block (issue 19;
the open release was removed by issue 28), on a coarse rubber block (40 x 30 x 20 mm,
4 x 3 x 2 elements)."""

import math

import numpy as np
import pytest

from fe_contact import (GRAVITY, Command, Friction, Gripper, Material, Model, Release, block_mesh, run,
                        run_release)
from fe_contact.fem.elasticity import internal_force
from fe_contact.stepping.measure import plate_wrench

WEIGHT_RTOL = 1e-8  # issue: normal forces sum to rho g V to 1e-8 relative
REST_FORCE_RTOL = 1e-8  # issue: in-plane contact forces at rest <= 1e-8 of the weight
STRESS_FREE_RTOL = 1e-9  # issue: strain energy after a lift <= 1e-9 of its loaded value
REST_POSE_RTOL = 1e-6  # issue: rest pose = commanded rigid motion to 1e-6 of the lag
SPRING_RTOL = 1e-9  # issue: gripper spring force = upper-face reaction
STIFF_GRIPPER_RTOL = 1e-6  # issue: a stiff gripper reproduces the rigid drive, relative to the lag
EQUILIBRIUM_TOL = 1e-8  # step reports' equilibrium error with weight

SIZE = (0.04, 0.03, 0.02)
DIVISIONS = (4, 3, 2)
RUBBER = dict(young=2e6, poisson=0.45)
DENSITY = 1000.0
PRESS = Command(dz=-4e-4)
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
TARGET = (3e-3, 1e-3, math.radians(5.0))  # 5 pushes


def model(density=0.0, gripper=None, quadrature=3, pad=None):
    return Model(block_mesh(SIZE, DIVISIONS), Material(**RUBBER, density=density),
                 Friction(0.6, 0.2, math.radians(20.0)), gripper=gripper or Gripper(), quadrature=quadrature, pad=pad)


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
    """Under a frictional pad that does not press, the weight alone rests on the floor."""
    m = model(DENSITY, pad=Friction(0.6, 0.6))
    _, reports = run(m, [Command()])
    rest = reports[-1]
    assert rest.converged and np.abs(rest.pad_reaction).max() <= 1e-20 * m.weight
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
    (lambda: Release("open", 3), "removed"),
    (lambda: Release("lift", 3, away=(1e-3,)), "away"),
    (lambda: Release("lift", 3, away=(math.nan, 0.0)), "away"),
])
def test_bad_input_names_the_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_a_command_cannot_open_the_gripper():
    """The open release is gone (its rest pose depended on an assumed pad stiffness):
    a Command has no grip to open; let go with Release("lift")."""
    with pytest.raises(TypeError, match="open"):
        Command(open=1.0)
