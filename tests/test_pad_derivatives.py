"""Exact derivatives of pushes with a frictional pad on the upper face and of the
rest after its release (issue 30 item 1b): floor and pad contacts stacked, each in
its own frame with its own friction, the whole linearised step solved at once (the
free block's stiffness is singular alone), against central differences; the check
fails when the pad's own friction, its rotation or the lift's heights are dropped."""

from dataclasses import replace

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
TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14, path_tol=1e-13)
"""path_tol = newton_tol: central differences of a release whose load steps stop at the default path_tol (1e-5)
difference where each loop stopped, not the path (measured: errors 1.6e-3 and 4.6e-2 against 1e-6); the exact
derivative moves by up to 4e-4 of its largest entry there (docs/derivatives.md)."""
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
"""Three load steps of the pad's load (issue 39: load control, the pad's height solved in each step),
by the default implicit midpoint rule."""
LIFT_PUSH = PUSH[:2]
EXTRAPOLATED, FALLBACK = "implicit midpoint: the half step extrapolated", "two backward-Euler halves"
PARTIAL = "of it, then backward Euler"
"""A midpoint load step extrapolated by a fraction ``0 < w < 1`` of its half step, then backward Euler."""


def released_statuses(monkeypatch, m, release):
    """The release's :func:`rollout_derivatives` and, per backward-Euler solve it
    differentiates after the pushes, the pad's contacts that stick and that slip."""
    seen, original = [], pad_sensitivity.PadLinearisation.__init__

    def recording(self, *args):
        original(self, *args)
        seen.append(np.bincount(self.node_status[m.n_lower:], minlength=3)[[NodeStatus.STICK, NodeStatus.SLIP]])

    monkeypatch.setattr(pad_sensitivity.PadLinearisation, "__init__", recording)
    result = rollout_derivatives(m, LIFT_PUSH, release=release)
    monkeypatch.undo()
    return result, np.array(seen[len(LIFT_PUSH):])


@pytest.mark.parametrize("pad_mu, steps, pad", [(2.0, 4, "sticks"), (0.5, 3, "mixed"), (0.25, 3, "mixed"),
                                                (0.05, 5, "slides")])
def test_rest_after_the_midpoint_release_of_a_pad(monkeypatch, pad_mu, steps, pad):
    """Issue 39 item 4: the rest's derivative through the release as it runs (the
    default implicit midpoint load steps: a half step extrapolated by the fraction
    ``w`` of it that keeps each contact on its branch, then, where ``w < 1``, a
    backward-Euler step; ``w``'s own derivative where a contact's bound sets it)
    against central differences of the same release: sticking (2), mixed (0.5;
    0.25, where the old lift's secant of the pad load degenerated: error 6.5) and
    sliding (0.05) pads; each solve's height the root of its load, ``F_z(h, p) =
    -P(p)``, by the implicit function theorem.  Each case has a step with ``0 < w
    < 1``.  Measured: 4.7e-6 (4 steps), 5.0e-6, 2.6e-6 (3 steps), 2.8e-6 (5
    steps).  Some step counts put the rest on a strongly curved branch, where the
    differences' own ``h^2`` error shows at this step: the pad 2 at 3 steps 9.8e-6
    (4.5e-6 at a tenth of the step), the sliding pad at 4 steps 1.8e-5 (4.7e-6 at a
    tenth): the exact derivative is the limit."""
    m = model(pad_mu)
    release = Release("lift", steps)
    result, statuses = released_statuses(monkeypatch, m, release)
    assert result.converged and result.differentiable, result.message or result.nondifferentiable()
    assert np.abs(result.reports[-1].pad_reaction).max() <= 1e-12 * m.weight  # let go
    messages = [r.message for r in result.reports[len(LIFT_PUSH):]]
    assert any(PARTIAL in t for t in messages), messages  # the extrapolation fraction's derivative checked
    loaded = statuses[statuses.sum(axis=1) > 0]  # the solves where the pad still presses
    sticks, slips = loaded[:, 0].sum(), loaded[:, 1].sum()
    assert {"sticks": slips == 0, "mixed": sticks > 0 and slips > 0, "slides": slips > 4 * sticks}[pad], loaded
    check = check_derivatives(m, LIFT_PUSH, release=release, rel_step=REL_STEP, parameters=("mu_x", "density"))
    print(pad_mu, check.max_error, check.worst())
    assert check.max_error <= 1e-5, check.worst()


def test_the_backward_euler_release_of_a_sliding_pad():
    """``Release.scheme = "backward_euler"``: one backward-Euler solve per load step."""
    m = model(0.15)
    release = Release("lift", 3, scheme="backward_euler")
    check = check_derivatives(m, LIFT_PUSH, release=release, rel_step=REL_STEP, parameters=())
    assert check.max_error <= 1e-5, check.worst()


def test_the_check_holds_a_default_path_tight_itself():
    """``check_derivatives`` solves a release's load steps to ``newton_tol`` itself (its
    exact rollout and its differences): a model at the default ``path_tol`` (1e-5)
    passes as TIGHT does (with the differences through the loose path: 1e-3 to 5e-2)."""
    m = replace(model(0.5), options=replace(TIGHT, path_tol=SolverOptions().path_tol))
    check = check_derivatives(m, LIFT_PUSH, release=Release("lift", 3), rel_step=REL_STEP, parameters=())
    assert check.max_error <= 1e-5, check.worst()


def _mutated_check(monkeypatch, name, value):
    import fe_contact.stepping.release_derivatives as release_derivatives

    monkeypatch.setattr(release_derivatives, name, value)
    return check_derivatives(model(0.5), LIFT_PUSH, release=RELEASE, rel_step=REL_STEP, parameters=())


def test_dropping_the_load_steps_root_fails(monkeypatch):
    check = _mutated_check(monkeypatch, "load_step_root", lambda d_out, force_z, load, d_load, d_state: (d_out, d_state))
    assert check.max_error > DROPPED_TERM_ERROR


@pytest.fixture(scope="module")
def rest_along_push_height():
    """Central difference of the rest pose ``(x, y, yaw)`` after the mixed pad's (mu
    0.5) midpoint release along the push's height ``dz[1]`` (a cheap column for the
    mutations below: two rollouts instead of a whole check)."""
    from fe_contact.stepping.derivative_check import _plain

    m, h = model(0.5), REL_STEP * 2e-4
    smooth = replace(m, options=replace(m.options, acceleration=0))
    rest = [_plain(smooth, [LIFT_PUSH[0], replace(LIFT_PUSH[1], dz=dz)], None, RELEASE)[-1, :3] for dz in (h, -h)]
    return (rest[0] - rest[1]) / (2 * h)


def _mutated_error(monkeypatch, numeric, name, value):
    """The largest relative error of the rest's exact derivative along ``dz[1]``
    against ``numeric`` with ``release_derivatives.<name>`` replaced by ``value``."""
    import fe_contact.stepping.release_derivatives as release_derivatives

    if name is not None:
        monkeypatch.setattr(release_derivatives, name, value)
    exact = rollout_derivatives(model(0.5), LIFT_PUSH, release=RELEASE, parameters=()).d_commands[-1, :3, 1, 2]
    return float(np.max(np.abs(exact - numeric) / np.abs(numeric)))


def test_extrapolating_without_the_factor_two_fails(monkeypatch, rest_along_push_height):
    """The midpoint's end differentiated as ``dS_m - dS_a`` (not ``2 dS_m - dS_a``):
    the rest's derivative along the push's height is off by more than its size
    (measured: exact to 7e-7; mutated, 1.3)."""
    import fe_contact.stepping.release_derivatives as release_derivatives

    assert _mutated_error(monkeypatch, rest_along_push_height, None, None) <= 1e-5
    original = release_derivatives._extrapolated

    def without_two(model_, new_state, report, d_start, half, d_start_out):
        halved = replace(half[1], **{k: 0.5 * getattr(half[1], k) for k in ("displacement", "pose", "plate")})
        return original(model_, new_state, report, d_start, (half[0], halved, half[2], 0.5 * half[3], half[4]),
                        d_start_out)

    assert _mutated_error(monkeypatch, rest_along_push_height, "_extrapolated", without_two) > DROPPED_TERM_ERROR


def test_dropping_the_start_load_from_the_mid_load_fails(monkeypatch, rest_along_push_height):
    """The mid load's derivative taken as the schedule's alone, ``dP_m = dP_b / 2``:
    the start's own load ``P_a`` (a function of the path) dropped (measured: the
    rest's yaw derivative -0.52 for 0.16)."""
    import fe_contact.stepping.release_derivatives as release_derivatives

    original = release_derivatives.middle_load

    def without_start(m, state, step):
        load, _ = original(m, state, step)
        return load, 0.5 * step.d_load

    assert _mutated_error(monkeypatch, rest_along_push_height, "middle_load", without_start) > DROPPED_TERM_ERROR


def test_a_transition_in_a_midpoint_step_is_flagged(monkeypatch):
    """The branch margins of a midpoint load step's backward-Euler solves (its half
    step, extrapolated; a fallback's two halves) are checked at that step
    (:mod:`~fe_contact.stepping.transitions`): a contact at a transition at the half
    step's end (margins made zero here) takes the rest's derivatives along the inputs
    that flip it (NaN) and is named in ``nondifferentiable``."""
    import fe_contact.stepping.derivatives as derivatives

    m, original, checked = model(0.5), derivatives.flipping_inputs, []

    def at_the_half_step(step, margin, *args):
        checked.append(step)
        return original(step, 0.0 * margin if step == 3 else margin, *args)

    monkeypatch.setattr(derivatives, "flipping_inputs", at_the_half_step)
    result = rollout_derivatives(m, LIFT_PUSH, release=RELEASE)
    messages = [r.message for r in result.reports]
    assert EXTRAPOLATED in messages[2] and PARTIAL in messages[3], messages
    assert checked.count(3) == 1 and checked.count(4) == 2  # the half step; its two solves (extrapolated in part)
    assert result.converged and result.nondifferentiable().startswith("step 3: "), result.nondifferentiable()
    assert {t.step for t in result.transitions} == {3}
    flipped = set().union(*(t.inputs for t in result.transitions))
    rest = result.jacobian()[-9:-6]
    assert flipped and all(np.all(np.isnan(rest[:, j])) == (j in flipped) for j in range(rest.shape[1]))


def test_a_load_step_past_a_jump_of_the_load_is_not_differentiated(monkeypatch):
    """A load step that ended past a jump of the pad's load (the pad let go at once,
    its load below the target: :mod:`~fe_contact.stepping.pad_load`) is no root of its
    load: the result says so instead of a number (every step misses here: the
    tolerance on the load set to 0)."""
    import fe_contact.stepping.midpoint as midpoint

    monkeypatch.setattr(midpoint, "MIDPOINT_LOAD_TOL", 0.0)  # read by midpoint.missed_load, the run's and the derivatives' test
    result = rollout_derivatives(model(0.5), LIFT_PUSH, release=RELEASE)
    assert not result.converged and "past a jump of the pad's load" in result.message, result.message
    assert result.message.startswith("step 3: ")


def test_an_extrapolation_fraction_set_by_two_contacts_is_not_differentiated(monkeypatch):
    """Where two contacts' bounds set a midpoint step's extrapolation fraction ``w < 1`` at once
    (a kink of the minimum: one-sided derivatives differ), the result says so instead of a
    number (made here by doubling the binding contact's bound in the derivative's view)."""
    import fe_contact.stepping.release_derivatives as release_derivatives

    original = release_derivatives.fraction_bounds

    def tied(model_, state, middle):
        bounds, kinds = original(model_, state, middle)
        i = int(np.argmin(bounds))
        bounds, kinds = np.append(bounds, bounds[i]), np.append(kinds, kinds[i])
        return bounds, kinds

    monkeypatch.setattr(release_derivatives, "fraction_bounds", tied)
    result = rollout_derivatives(model(0.5), LIFT_PUSH, release=RELEASE)
    assert not result.converged and "set by two contacts at once" in result.message, result.message
