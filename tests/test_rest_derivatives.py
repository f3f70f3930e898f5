"""Exact derivatives of the rest pose after a bonded lift (issue 30 item 1):
the release's heights are the device's, the last one set by the root of the
plate's vertical force (implicit function theorem), against central
differences of whole rollouts with their release; the check fails when the
root condition or the put-down's own-weight target is dropped."""

import numpy as np
import pytest

import fe_contact.stepping.derivatives as derivatives
import fe_contact.stepping.release as release
from fe_contact import Command, Friction, Gripper, Material, Model, NodeStatus, SolverOptions, block_mesh
from fe_contact.stepping.derivative_check import check_derivatives
from fe_contact.stepping.derivatives import OUTPUTS, rollout_derivatives
from fe_contact.stepping.release import Release

REL_TOL = 1e-6
"""Agreement of exact and central-difference derivatives (normalised, see check_derivatives)."""
DROPPED_TERM_ERROR = 1e-3
"""A derivative with a term dropped is off by at least this."""
REL_STEP = 3e-5
"""Central differences' step: the put-down's root is found to 1e-10 of the weight (that noise over the step
weighs against their h^2 error: max errors 1.9e-6, 8.1e-7, 4.3e-6 at 1e-5, 3e-5, 1e-4 on a sliding push)."""
TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14)
SIZE = (0.02, 0.02, 0.01)
PUSH = [Command(dz=-2e-4), Command(dx=3e-4, dy=1e-4, dtheta=0.01)]
LIFT = Release("lift", 3)


def model(density=1500.0, gripper=None, mu=(0.3, 0.15), divisions=(2, 2, 1)):
    return Model(block_mesh(SIZE, divisions), Material(2e6, 0.3, density), Friction(*mu, 0.4), options=TIGHT,
                 gripper=gripper or Gripper())


def assert_agrees(check, tol=REL_TOL):
    # the rest's vertical plate force is zero by the root condition (its derivative exactly 0): its
    # central difference is the put-down's tolerance (1e-10 of the weight) over the step, left out
    root = check.outputs.index("force_z[rest]")
    assert np.abs(check.analytic[root]).max() <= 1e-20
    check.error[root] = 0.0
    assert check.max_error <= tol, check.worst()


def test_rest_after_a_bonded_lift_with_weight():
    m = model()
    result = rollout_derivatives(m, PUSH, release=LIFT)
    assert result.outputs.shape == (3, 9) and result.d_commands.shape == (3, 9, 2, 4)
    assert abs(result.outputs[-1, OUTPUTS.index("force_z")]) <= 1e-9 * m.weight  # put down where the plate carries 0
    assert any(np.all(r.node_status == NodeStatus.SEPARATED) for r in result.reports)  # it hung in between
    assert_agrees(check_derivatives(m, PUSH, release=LIFT, rel_step=REL_STEP))


def test_rest_after_a_sliding_push_and_a_finer_lift():
    m = model(mu=(0.1, 0.05), divisions=(3, 2, 1))
    push = [Command(dz=-2e-4), Command(dx=4e-4, dy=-2e-4, dtheta=-0.02)]
    assert_agrees(check_derivatives(m, push, release=Release("lift", 5), rel_step=REL_STEP,
                                    parameters=("mu_x", "mu_y", "angle", "young", "density")))


def test_rest_after_a_lift_with_a_compliant_gripper(monkeypatch):
    # the plate balance of the hanging block has no force scale but rounding: its tolerance (1e-12 at
    # the tightest that converges) over the step is the central differences' noise, measured 9.0e-6,
    # 3.4e-6, 8.1e-6 at steps 3e-5, 1e-4, 3e-4 (their h^2 error): checked to 1e-5
    import fe_contact.stepping.gripper as gripper
    monkeypatch.setattr(gripper, "PLATE_TOL", 1e-12)
    m = model(gripper=Gripper(2e3, 2.0))
    check = check_derivatives(m, PUSH, release=LIFT, rel_step=1e-4,
                              parameters=("mu_x", "angle", "density", "stiffness_xy", "stiffness_yaw"))
    assert_agrees(check, tol=1e-5)


def test_the_root_condition_sets_the_last_height(monkeypatch):
    # the put-down's last height is the root of F_z: whatever the regula falsi's own derivative of
    # its last target, the implicit function theorem replaces it; without the root, it is off
    m = model()
    original, calls = derivatives.release_height_derivative, []

    def wrong_last(*args):
        calls.append(1)
        out = original(*args)
        return 0.0 * out if len(calls) == n else out

    n = len(rollout_derivatives(m, PUSH, release=LIFT).reports) - len(PUSH)
    monkeypatch.setattr(derivatives, "release_height_derivative", wrong_last)
    assert_agrees(check_derivatives(m, PUSH, release=LIFT, rel_step=REL_STEP))
    calls.clear()
    monkeypatch.setattr(derivatives, "put_down_root", lambda schedule, d_rest, force_z, d_state: d_state)
    assert check_derivatives(m, PUSH, release=LIFT, rel_step=REL_STEP).max_error > DROPPED_TERM_ERROR


def test_dropping_the_put_down_targets_fails(monkeypatch):
    # the put-down overshoots to -W / (2 k) and comes back: some contacts slip on the way, so its
    # targets (functions of E, rho and of the forces met) are part of the path
    m = model()
    monkeypatch.setattr(release, "put_down_target", lambda *args: (original(*args)[0], {}))
    check = check_derivatives(m, PUSH, release=LIFT, rel_step=REL_STEP, parameters=("young", "density"))
    assert check.error[-9:].max() > DROPPED_TERM_ERROR


original = release.put_down_target


def test_release_arguments_are_checked():
    m = model()
    with pytest.raises(ValueError, match="release must be"):
        rollout_derivatives(m, PUSH, release="lift")


def test_a_weightless_lift_rises_to_its_height():
    # nothing to put down: the release rises to its height and ends (it used to go on to the put-down's
    # search, whose bracket has no pulling end without weight: ValueError from min())
    from fe_contact import run
    from fe_contact.stepping.sequence import run_release
    m = Model(block_mesh(SIZE, (2, 2, 1)), Material(2e6, 0.3), Friction(0.3, 0.15, 0.4))
    state, reports = run(m, PUSH)
    end, _ = run_release(m, state, Release("lift", 2, height=1e-4), reports[-1])
    np.testing.assert_allclose(end.upper_translation[2], 1e-4, rtol=1e-12)
