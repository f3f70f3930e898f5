"""Issue 39, item 2 (the release's cost): a frictional pad's load steps start their
Newton loop from the last load step's path extrapolated in the pad's load
(:func:`fe_contact.stepping.predictor.load_path_guess`), not from the step's start:
the same rest pose to the Newton tolerance, in fewer Newton iterations; a guess that
misleads the loop costs a second loop from the start, never the step.  The block of
benchmarks/release_refinement.py (40 x 30 x 20 mm, 3 x 2 x 2), a pad 0.3 x the floor's
friction (measured: 65 / 68 midpoint and 46 / 48 backward-Euler Newton iterations with /
without the predictor, rest poses 2.3e-11 and 1.2e-11 of the lag apart; the midpoint's 65 were 55
before its load steps were extrapolated by a fraction that keeps the contacts on their branches,
which takes a second solve in 4 of its 7 midpoint steps here)."""

import dataclasses
import math

import numpy as np
import pytest

import fe_contact.stepping.sequence as sequence
from fe_contact import (Command, Friction, Material, Model, PadLoad, Release, SolverOptions, block_mesh,
                        release_to_rest, run, step)
from fe_contact.stepping.pad_load import pad_normal_load
from fe_contact.stepping.predictor import MAX_LOAD_EXTRAPOLATION, StepGuess, load_path_guess

FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
SAME_REST = 2e-8
"""Rest poses with and without the predictor differ by at most this fraction of the loaded lag (Newton tolerance
1e-10; measured 2.1e-11 and 1.2e-11)."""
BOUND = {"midpoint": 66, "backward_euler": 47}
"""The release's Newton iterations at most (measured 65 and 46 with the predictor, 68 and 48 from each step's start)."""


@pytest.fixture(scope="module")
def loaded():
    """The block pressed 0.4 mm and pushed twice by a pad of 0.3 x the floor's friction."""
    pad = Friction(0.3 * FLOOR[0], 0.3 * FLOOR[1], FLOOR[2])
    # path_tol = newton_tol: the predictor's claim is the same rest to the Newton tolerance; at the default path_tol
    # the load steps stop at 1e-5 and where a loop from another start stops differs by that much (tests/test_path_tol.py)
    model = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
                  quadrature=2, pad=pad, options=SolverOptions(path_tol=1e-10))
    state, pushes = run(model, [Command(dz=-4e-4), PUSH, PUSH])
    return model, state, pushes


def _release(loaded, scheme):
    model, state, pushes = loaded
    _, reports, rest = release_to_rest(model, state, Release("lift", 8, scheme=scheme), pushes[-1])
    assert rest.settled, rest.reason
    return reports[-1].lower_centroid[:2], sum(r.newton_iterations for r in reports)


@pytest.mark.parametrize("scheme", sorted(BOUND))
def test_predicted_load_steps_reach_the_same_rest_in_fewer_iterations(loaded, scheme, monkeypatch):
    rest, iterations = _release(loaded, scheme)
    with monkeypatch.context() as patch:
        patch.setattr(sequence, "load_path_guess", lambda *args: None)  # every load step from its start
        rest_start, iterations_start = _release(loaded, scheme)
    lag = np.linalg.norm(loaded[2][-1].lag)
    print(f"{scheme}: {iterations} / {iterations_start} Newton iterations, rest "
          f"{np.linalg.norm(rest - rest_start) / lag:.2e} of the lag apart")
    assert np.linalg.norm(rest - rest_start) <= SAME_REST * lag
    assert iterations < iterations_start
    assert iterations <= BOUND[scheme]


def _on_a_line(model, state, slope: float, loads):
    """Two states of a made-up path linear in the load: ``loads`` (N) at the pad."""
    states = []
    for p in loads:
        r = np.array(state.reaction, dtype=float)
        r[model.n_lower:, 0] = p / (r.shape[0] - model.n_lower)
        states.append(dataclasses.replace(state, displacement=state.displacement + slope * p, reaction=r,
                                          upper_translation=state.upper_translation + [0.0, 0.0, -slope * p]))
    return states


def test_the_guess_extrapolates_a_linear_path_exactly_and_only_forwards(loaded):
    model, state, _ = loaded
    before, after = _on_a_line(model, state, 1e-7, (10.0, 8.0))
    loads = (pad_normal_load(model, before), pad_normal_load(model, after))
    guess = load_path_guess(before, after, loads, 5.0)
    exact = _on_a_line(model, state, 1e-7, (5.0,))[0]
    np.testing.assert_allclose(after.displacement + guess.correction, exact.displacement, rtol=0, atol=1e-18)
    np.testing.assert_allclose(guess.reaction, exact.reaction, rtol=1e-12, atol=1e-12)
    assert guess.height == pytest.approx(exact.upper_translation[2], rel=1e-12)
    assert load_path_guess(before, after, loads, 9.0) is None  # backwards
    assert load_path_guess(before, after, loads, 8.0 - 2.0 * MAX_LOAD_EXTRAPOLATION - 1.0) is None  # too far
    assert load_path_guess(after, after, (8.0, 8.0), 5.0) is None  # no step to extrapolate


def test_a_misleading_guess_costs_a_second_loop_not_the_step(loaded):
    model, state, pushes = loaded
    load = 0.7 * -pushes[-1].upper_force[2]
    plain, plain_report = step(model, state, PadLoad(load))
    flat = np.zeros((model.mesh.n_nodes, 3))
    flat[:, 2] = -1.5 * model.mesh.nodes[:, 2]  # every element inverted: the loop breaks down at its start
    wild = StepGuess(flat, np.array(state.reaction), height=0.0)
    guessed, report = step(model, state, PadLoad(load), guess=wild)
    assert plain_report.converged and report.converged, report.message
    assert np.abs(guessed.displacement - plain.displacement).max() <= 1e-9 * np.abs(plain.displacement).max()
    assert report.newton_iterations >= plain_report.newton_iterations  # both loops counted (the first broke down at 0)
