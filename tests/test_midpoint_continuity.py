"""The midpoint release's rest pose is continuous in the commands (issue 39, rule 1).

Each load step of the implicit midpoint rule extrapolates its half step by the largest
fraction ``w`` in [0, 1] that keeps every contact on the branch of the contact law it holds
at the mid load (``midpoint.extrapolation_fraction``), then goes on by backward Euler where
``w < 1``; each contact's bound is continuous in the data.  The rule it replaced chose between
the whole extrapolation and two backward-Euler halves by a threshold on the contact forces,
and on this case (the rest-target plan of tests/test_plan_session.py at its first Gauss-Newton
step: 3 pushes, 4 load steps, pad 0.8) a push 1e-9 m longer flipped that choice and moved the
rest by 1.2 um: the forward difference of the rest along the push was 1222 at a step of 1e-9 m
and 1.0027 at 1e-8 m.  Now both are 0.996405, as is the rollout's exact derivative."""

import math

import numpy as np
import pytest

from fe_contact import Command, Friction, Material, Model, Release, block_mesh, release_to_rest, run

PUSHES = (Command(dx=0.0010346509289749393, dy=0.00035598239375732055, dtheta=0.029325210279790372),
          Command(dx=0.0010268722502936494, dy=0.0003422955365706454, dtheta=0.02940769319924063),
          Command(dx=0.0010269940597477187, dy=0.00034256965508804233, dtheta=0.02939999051825764))
SLOPES_AGREE = 1e-3
"""Forward differences of the rest at steps 1e-9 and 1e-8 m agree to this fraction (Newton tolerance 1e-10 of
the forces: about 4e-14 m of rest, 4e-5 of the slope at 1e-9 m; measured 7.6e-8)."""


@pytest.fixture(scope="module")
def pressed():
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0),
              Friction(0.6, 0.2, math.radians(20.0)), quadrature=2, pad=Friction(0.8, 0.8, 0.0))
    state, _ = run(m, [Command(dz=-4e-4)])
    return m, state


def rest_x(pressed, longer: float) -> float:
    m, state = pressed
    pushes = [Command(PUSHES[0].dx + longer, PUSHES[0].dy, 0.0, PUSHES[0].dtheta), *PUSHES[1:]]
    state, reports = run(m, pushes, state)
    _, release, rest = release_to_rest(m, state, Release("lift", 4), reports[-1])
    assert rest.settled, rest.reason
    return float(release[-1].lower_centroid[0])


def test_the_rest_is_smooth_in_a_push_length(pressed):
    x0 = rest_x(pressed, 0.0)
    slopes = [(rest_x(pressed, h) - x0) / h for h in (1e-9, 1e-8)]
    assert abs(slopes[0] - slopes[1]) <= SLOPES_AGREE * abs(slopes[1]), slopes
    assert 0.9 < slopes[1] < 1.1, slopes  # the rest follows the push


def test_each_contact_bounds_the_extrapolation_where_it_would_leave_its_branch(pressed):
    """``midpoint.fraction_bounds`` on made-up forces at the step's start ``S_a`` and mid load
    ``S_m`` of the pressed block: a slipping contact whose normal force falls 2 -> 0.5 N reaches 0
    at ``w = 0.5 / 1.5``; a sticking one whose tangential force grows 0 -> 0.6 mu r_n leaves its
    cone at ``w = 2 / 3``; one that opened in the half step bounds ``w`` at 0; a slipping one (on
    its cone at the mid load) bounds nothing; the fraction is the smallest bound."""
    from dataclasses import replace

    from fe_contact.stepping.midpoint import fraction_bounds

    m, state = pressed
    mu = m.contacts.mu_x
    ra, rm = np.array(state.reaction), np.array(state.reaction)
    ra[:4], rm[:4] = [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]
    ra[0], rm[0] = [2.0, 2.0 * mu[0], 0.0], [0.5, 0.5 * mu[0], 0.0]  # slipping (on its cone), its force falling
    rm[1, 1] = 0.6 * mu[1]  # sticking, towards the cone
    ra[2, 1], rm[2, 1] = mu[2], mu[2] * 1.0  # slipping at both: on the cone
    rm[3] = 0.0  # opened in the half step
    bounds, kinds = fraction_bounds(m, replace(state, reaction=ra), replace(state, reaction=rm))
    assert bounds[0] == pytest.approx(1.0 / 3.0) and kinds[0] == "force"
    assert bounds[1] == pytest.approx(2.0 / 3.0) and kinds[1] == "cone"
    assert bounds[2] == np.inf
    assert bounds[3] == 0.0 and kinds[3] == "force"
