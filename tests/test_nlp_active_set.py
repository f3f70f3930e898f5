"""A warm solve of the planning NLP first solves the smooth NLP of its warm start's branch of
the complementarity (issue 41's first re-plan) and keeps it only where it is a solution of
the full MPCC; else it falls back to the full warm MPCC solve.  Both paths are checked
against the full warm solve from the same start (``ReducedPlanner.active_set = False``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pushplan.planning.nlp import ACTIVE_SET_MAX_ITER, ReducedPlanner
from pushplan.planning.reduced_model import PushParameters
from test_planner import STEEL, _spec

AGREE = 1e-5  # of max_step: the two paths' commands and poses (the relaxation, COMPLEMENTARITY_EPS)


def _both(params: PushParameters, spec, first: dict, then: dict):
    """Plan ``first`` cold, then warm-solve ``then`` from it with and without the active set."""
    planner = ReducedPlanner(params, spec)
    planner.retarget(dataclasses.replace(spec, **first))
    start = planner.solve()
    assert start.success
    planner.retarget(dataclasses.replace(spec, **then))
    out = []
    for flag in (True, False):
        planner.active_set = flag
        out.append(planner.solve(warm=start))
    return start, *out


def _apart(a, b) -> float:
    return max(float(np.abs(a.commands - b.commands).max()), float(np.abs(a.lower - b.lower).max()),
               float(np.abs(a.upper - b.upper).max()))


def test_warm_solve_keeps_the_active_set_and_the_mpcc_answer():
    """A target moved by 2 % keeps every step's branch: the smooth NLP answers, equal to
    the full MPCC's to its relaxation, in fewer ipopt iterations; no step is on both bounds."""
    spec = _spec(x=9e-4, y=9e-4)
    start, smooth, full = _both(STEEL, spec, {}, {"target": (9.2e-4, 8.9e-4, 0.0)})
    assert smooth.success and full.success and full.path == "mpcc"
    assert smooth.path == "active_set"
    assert _apart(smooth, full) < AGREE * spec.max_step
    slides = start.variables["sigma"].ravel() > 1 - start.variables["rho"].ravel()
    assert slides.any()
    assert (smooth.variables["sigma"].ravel()[slides] > 0.1).all()
    assert smooth.iterations < full.iterations


def _from(start, stuck: int):
    """``start`` with step ``stuck`` stuck half-way below the limit surface (sigma = 0, rho = 0.5)."""
    v = {k: np.array(x) for k, x in start.variables.items()}
    v["sigma"][0, stuck], v["rho"][0, stuck] = 0.0, 0.5
    return dataclasses.replace(start, variables=v)


@pytest.mark.parametrize("stuck", [1, 3])
def test_warm_solve_falls_back_when_a_stuck_step_wants_to_slip(stuck):
    """A warm start with one step stuck where the answer slides: the smooth NLP keeps it
    stuck and its ``sigma >= 0`` multiplier says it wants to slip, so the full MPCC is
    solved from the same start and answers (bit for bit the full warm solve's); both ipopt
    runs are counted.  Step 3 (the last) alone would give a stationary point of its branch
    with a 5e-7 higher objective: the sticking steps' test is what catches it."""
    spec = _spec(x=9e-4, y=9e-4)
    planner = ReducedPlanner(STEEL, spec)
    start = planner.solve()
    planner.retarget(dataclasses.replace(spec, target=(9.2e-4, 8.9e-4, 0.0)))
    fallback = planner.solve(warm=_from(start, stuck))
    planner.active_set = False
    full = planner.solve(warm=_from(start, stuck))
    assert fallback.path == "mpcc_after_active_set_switch" and fallback.success
    assert _apart(fallback, full) == 0.0
    assert fallback.iterations > full.iterations


def test_warm_solve_falls_back_when_the_active_set_nlp_does_not_converge():
    """Reversing the target turns every sliding step round: the all-sliding branch does not
    converge within ``ACTIVE_SET_MAX_ITER`` and the full MPCC answers."""
    spec = _spec(x=9e-4, y=9e-4)
    start, fallback, full = _both(STEEL, spec, {}, {"target": (-9e-4, -9e-4, 0.0)})
    assert fallback.path == "mpcc_after_active_set_failed"
    assert _apart(fallback, full) == 0.0
    assert fallback.iterations == full.iterations + ACTIVE_SET_MAX_ITER


@pytest.mark.parametrize("flag", [True, False])
def test_cold_solve_never_takes_the_active_set(flag):
    planner = ReducedPlanner(STEEL, _spec(x=9e-4, y=9e-4))
    planner.active_set = flag
    assert planner.solve().path == "mpcc"
