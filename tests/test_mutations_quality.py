"""Tests that kill the mutations of issue 43 the rest of the suite let through (which
test guards which equation: tests/test_mutations.md):

- the two-mesh Richardson estimate of :mod:`pushplan.identify.uncertainty` (the factor
  ``r^p / (r^p - 1)``), against a sequence of exact order ``p``;
- a mocap block's orientation written into MuJoCo by the coupling (``mocap_quat``);
- the pad's friction axes (their angle's sense, ``mu_x`` along ``t_x``): the pad's force on a
  block held by the floor while the pad slides, against the elliptic cone's law.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fe_contact import Command, Friction, Material, Model, block_mesh, run
from pushplan.identify.uncertainty import ASSUMED_ORDER, REFINEMENT, SAFETY_FACTOR, discretisation_shift

from test_mujoco_coupling import ARM_XML, HOLD_TOL, _arm_run

SLIDING_RTOL = 2e-3  # |T| / N of a pad sliding along a friction axis against mu (3 x 2 x 2 block)
DIRECTION_TOL_DEG = 0.1  # ... and its direction against the slide's
OFF_AXIS_TOL_DEG = 3.0  # a slide between the axes: the force's direction (elliptic law) on a deforming block


# -- Richardson's two-mesh estimate (identify/uncertainty.py) -----------------------------------
def test_the_mesh_term_is_the_safety_factor_times_the_error_of_an_exact_order_sequence():
    """``y(h) = y* + C h^p`` with ``p = ASSUMED_ORDER``: the estimate from ``h`` and
    ``h / REFINEMENT`` is ``SAFETY_FACTOR (y(h) - y*)`` exactly (Richardson's
    extrapolation is exact for such a sequence), and with ``J = C0 = I``, ``sigma = 1``
    the shift is its negative and the chi-square its square."""
    y_star, C, h = np.array([1.0, -2.0, 0.5]), np.array([3.0, 0.2, -7.0]), 0.1
    y_h = y_star + C * h**ASSUMED_ORDER
    y_fine = y_star + C * (h / REFINEMENT) ** ASSUMED_ORDER
    d, chi2 = discretisation_shift(np.eye(3), np.ones(3), y_h, y_fine, np.eye(3))
    np.testing.assert_allclose(d, -SAFETY_FACTOR * (y_h - y_star), rtol=1e-12)
    assert chi2 == pytest.approx(float(np.sum((SAFETY_FACTOR * (y_h - y_star)) ** 2)), rel=1e-12)


# -- a mocap block in the coupling (mujoco/coupling.py) ------------------------------------------
def test_a_mocap_block_yawed_by_the_fe_is_shown_yawed_in_mujoco(tmp_path):
    """The docstring offers a mocap block: the yawed arm scene of
    tests/test_mujoco_coupling.py with the block a mocap body (no free joint).  The FE
    block turns; MuJoCo's block geom follows it, position and yaw, inside every period."""
    text = ARM_XML.read_text()
    for old, new in (
        ('<body name="block" pos="0 0 0.005">', '<body name="block" mocap="true" pos="0.013 -0.027 0.005" '
                                                'euler="0 0 25">'),
        ('<freejoint name="block_free"/>', ''),
        ('<body name="carriage_x" pos="0 0 0.1"', '<body name="carriage_x" pos="0.013 -0.027 0.1"'),
        ('<body name="hand" pos="0 0 -0.09">', '<body name="hand" pos="0 0 -0.09" euler="0 0 25">'),
        ('<numeric name="pushplan_poisson" data="0.3"/>',
         '<numeric name="pushplan_poisson" data="0.3"/><numeric name="pushplan_friction_angle" data="10"/>'),
    ):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "mocap_arm.xml"
    path.write_text(text)
    m, d, scene, coupler, plan, out = _arm_run(40, path)
    assert m.body("block").mocapid[0] >= 0 and m.nmocap == 1
    assert abs(coupler.lower_yaw) * max(scene.scenario.size) > 100 * HOLD_TOL  # the block turns
    assert out["hold"] <= HOLD_TOL, out


# -- the pad's friction axes (stepping/model.py, contact/bodies.py) -------------------------------
def _pad_force(push_deg: float) -> np.ndarray:
    """The pad's force on the block (world, N) after a press and a 2 mm slide of the pad
    along ``push_deg``: floor friction 2 holds the block, the pad (0.4, 0.2) at 30 deg slides."""
    model = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.3), Friction(2.0, 2.0),
                  quadrature=2, pad=Friction(0.4, 0.2, math.radians(30.0)))
    p = math.radians(push_deg)
    _, reports = run(model, [Command(dz=-4e-4)] + [Command(dx=1e-3 * math.cos(p), dy=1e-3 * math.sin(p))] * 2)
    assert all(r.converged for r in reports), reports[-1].message
    assert reports[-1].n_slip == 0  # the floor holds: the pad slides
    return reports[-1].upper_force


@pytest.mark.parametrize("push_deg, mu", [(30.0, 0.4), (120.0, 0.2)])
def test_a_pad_sliding_along_its_axis_pulls_with_that_axis_coefficient(push_deg, mu):
    """Sliding along ``t_x = (cos 30, sin 30)`` the pad's tangential force is ``mu_x N``
    along the slide; along ``t_y`` it is ``mu_y N`` (the friction frame of sect. 3)."""
    F = _pad_force(push_deg)
    assert math.hypot(F[0], F[1]) / abs(F[2]) == pytest.approx(mu, rel=SLIDING_RTOL)
    assert math.degrees(math.atan2(F[1], F[0])) == pytest.approx(push_deg, abs=DIRECTION_TOL_DEG)


def test_a_pad_sliding_between_its_axes_pulls_along_the_elliptic_law():
    """A slide at 45 deg from ``t_x``: the force of maximum dissipation on the ellipse is
    ``(mu_x^2 v_x, mu_y^2 v_y)``, at ``atan(mu_y^2 / mu_x^2)`` = 14.0 deg from ``t_x``
    (44.0 deg in the world), not along the slide (75 deg)."""
    F = _pad_force(75.0)
    expected = 30.0 + math.degrees(math.atan(0.2**2 / 0.4**2))
    assert math.degrees(math.atan2(F[1], F[0])) == pytest.approx(expected, abs=OFF_AXIS_TOL_DEG)


# -- the rest check (stepping/release.py; public: fe_contact.rest_check) ------------------------
def test_a_block_nudged_off_equilibrium_is_reported_out_of_balance():
    """``Rest`` promises "settled" only when every node not held is in equilibrium to
    ``SETTLE_FORCE`` (1e-9) of the weight (docs/release.md): a pressed block's converged
    state, its nodes nudged by 1 nm, is out of balance by ~1e-4 of the weight, which the
    check must report and measure (the un-nudged state: 100x less)."""
    from dataclasses import replace

    from fe_contact import Release, ReleaseSchedule, rest_check

    model = Model(block_mesh((0.04, 0.03, 0.02), (2, 2, 1)), Material(2e6, 0.3, density=1000.0),
                  Friction(0.6, 0.2, math.radians(20)), quadrature=2)
    state, reports = run(model, [Command(dz=-4e-4)])
    assert reports[-1].converged
    schedule = ReleaseSchedule(model, Release("lift", 4), state, reports[-1])
    plain = rest_check(model, state, reports[-1], schedule)
    assert not plain.settled and "pad still carries" in plain.reason  # the plate presses
    nudge = 1e-9 * np.random.default_rng(0).standard_normal(state.displacement.shape)
    nudged = rest_check(model, replace(state, displacement=state.displacement + nudge), reports[-1], schedule)
    assert 1e-7 * model.weight < nudged.imbalance < 1e-2 * model.weight  # far above 1e-9, far below the weight
    assert plain.imbalance < 1e-2 * nudged.imbalance
    assert "out of balance" in nudged.reason
