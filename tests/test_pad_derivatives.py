"""Exact derivatives of pushes with a frictional pad on the upper face and of the
rest after its release (issue 30 item 1b): floor and pad contacts stacked, each in
its own frame with its own friction, the whole linearised step solved at once (the
free block's stiffness is singular alone), against central differences; the check
fails when the pad's own friction, its rotation or the lift's heights are dropped."""

import numpy as np
import pytest

import fe_contact.stepping.pad_sensitivity as pad_sensitivity
from fe_contact import Command, Friction, Material, Model, NodeStatus, SolverOptions, block_mesh
from fe_contact.stepping.derivative_check import check_derivatives
from fe_contact.stepping.derivatives import rollout_derivatives
from fe_contact.stepping.release import Release

REL_TOL = 1e-6
DROPPED_TERM_ERROR = 1e-3
REL_STEP = 1e-4
"""Central differences' step (at 1e-5 their noise on the entries that vanish by symmetry, 1e-13 m, over
the step gives 6e-6; at 1e-4: 7e-7)."""
TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14)
SIZE = (0.02, 0.02, 0.01)
PUSH = [Command(dz=-2e-4), Command(dx=2e-4, dy=1e-4, dtheta=0.01), Command(dx=-1e-4, dy=2e-4)]


def model(pad_mu):
    return Model(block_mesh(SIZE, (2, 2, 1)), Material(2e6, 0.3, 800.0), Friction(0.3, 0.15, 0.4), options=TIGHT,
                 pad=Friction(pad_mu, 0.8 * pad_mu, 0.3))


def pad_statuses(monkeypatch, m, commands):
    seen, original = [], pad_sensitivity.PadLinearisation.__init__

    def recording(self, *args):
        original(self, *args)
        seen.append(np.bincount(self.node_status[m.n_lower:], minlength=3))

    monkeypatch.setattr(pad_sensitivity.PadLinearisation, "__init__", recording)
    rollout_derivatives(m, commands)
    monkeypatch.undo()
    return seen


@pytest.mark.parametrize("pad_mu, pad_slips", [(2.0, False), (0.15, True)])
def test_push_with_a_frictional_pad(monkeypatch, pad_mu, pad_slips):
    m = model(pad_mu)
    last = pad_statuses(monkeypatch, m, PUSH)[-1]
    assert (last[NodeStatus.SLIP] == m.mesh.upper.size) == pad_slips, last
    check = check_derivatives(m, PUSH, rel_step=REL_STEP)
    assert check.max_error <= REL_TOL, check.worst()


def test_dropping_the_pads_own_friction_fails(monkeypatch):
    m = model(0.15)
    original = pad_sensitivity.law_jacobian

    def floor_friction_everywhere(separated, slip, r, u_t, mu_x, mu_y):
        return original(separated, slip, r, u_t, mu_x[0], mu_y[0])

    monkeypatch.setattr(pad_sensitivity, "law_jacobian", floor_friction_everywhere)
    assert check_derivatives(m, PUSH, rel_step=REL_STEP, parameters=()).max_error > DROPPED_TERM_ERROR


def test_dropping_the_pads_rotation_fails(monkeypatch):
    # the pad's motion at a node turns with the command's dtheta about the pad's centre
    m = model(2.0)
    original = pad_sensitivity.PadLinearisation._kinematics_derivative

    def without_turn(self, d_start, d_pose_start, d_pose):
        d_pose, d_pose_start = d_pose.copy(), d_pose_start.copy()
        d_pose[3] = d_pose_start[3] = 0.0
        return original(self, d_start, d_pose_start, d_pose)

    monkeypatch.setattr(pad_sensitivity.PadLinearisation, "_kinematics_derivative", without_turn)
    check = check_derivatives(m, PUSH, rel_step=REL_STEP, parameters=())
    assert check.error[:, check.inputs.index("dtheta[1]")].max() > DROPPED_TERM_ERROR


RELEASE = Release("lift", 3)
"""Three load steps of the pad's load (issue 39: load control, the pad's height solved in each step)."""
LIFT_PUSH = PUSH[:2]


@pytest.mark.parametrize("pad_mu", [2.0, 0.25, 0.15, 0.05])
def test_rest_after_the_release_of_a_pad(pad_mu):
    """Sticking (2), mixed (0.25, where the old lift's secant of the pad load
    degenerated: error 6.5) and sliding (0.15, 0.05) pads: each load step's
    height is the root of its load, ``F_z(h, p) = f F_z,0(p)``, differentiated
    by the implicit function theorem."""
    m = model(pad_mu)
    result = rollout_derivatives(m, LIFT_PUSH, release=RELEASE)
    assert result.converged, result.message
    assert np.abs(result.reports[-1].pad_reaction).max() <= 1e-12 * m.weight  # let go
    check = check_derivatives(m, LIFT_PUSH, release=RELEASE, rel_step=REL_STEP, parameters=("mu_x", "density"))
    print(pad_mu, check.max_error, check.worst())
    assert check.max_error <= 1e-5, check.worst()


def test_dropping_the_load_steps_root_fails(monkeypatch):
    import fe_contact.stepping.derivatives as derivatives
    monkeypatch.setattr(derivatives, "load_step_root", lambda d_out, force_z, load, d_load, d_state: (d_out, d_state))
    check = check_derivatives(model(2.0), LIFT_PUSH, release=RELEASE, rel_step=REL_STEP, parameters=())
    assert check.max_error > DROPPED_TERM_ERROR
