"""The warm planner of the closed loop (issue 32 items 1-2): a :class:`PlanSession` built
once, advanced one FE step per executed push, re-planning with the NLP it built and the
calibration it fitted, against cold re-plans (:func:`replan` from the press) of the same
observations.  The model of tests/test_closed_loop.py (4 x 4 x 2, the planning mesh is the
block mesh): a warm re-plan on the planning mesh and a cold one verify on the same mesh."""

import tomllib

import numpy as np
import pytest

from pushplan.config import parse_scenario
from pushplan.config.commands import planar_commands
from pushplan.config.plan import parse_plan, press_commands
from pushplan.planning import planner as planner_module
from pushplan.planning.planner import PlanSession, _start_lag, plan
from pushplan.planning.replan import replan
from pushplan.planning.rollouts import FeRollouts
from pushplan.planning.target import within_tolerance
from pushplan.run import drive
from pushplan.run.observations import observations_from_steps

from test_closed_loop import MODEL, PLAN

COMMANDS_AGREE = 1e-2
"""Warm vs cold re-planned commands, relative to max_step (their calibrations differ: the
warm one is the first plan's, the cold one a naive push of the remaining steps)."""
STATE_AGREE = 1e-9
"""The lag after the executed pushes, stepped one push at a time vs in one run, relative."""


@pytest.fixture(scope="module")
def setting():
    model = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.3, mu_y=0.15) + PLAN))
    truth = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.39, mu_y=0.195)))
    spec = parse_plan(model)
    first = plan(model, spec, baseline=False)
    run = drive(truth.model(), tuple(_press(model)) + tuple(planar_commands(first.commands[:2])))
    return model, spec, first, run


def _press(scenario):
    return press_commands(scenario)


def _observations(run, n_pushes: int, n_press: int):
    return observations_from_steps(list(run.summary.steps[:n_press + n_pushes]))


def test_warm_replans_agree_with_cold_ones_and_reuse_the_nlp(setting):
    model, spec, first, run = setting
    n_press = len(_press(model))
    session = PlanSession(model, spec, verify=False)
    session.follow(first)
    for pushes in (1, 2):
        obs = _observations(run, pushes, n_press)
        warm, start = replan(model, spec, obs, baseline=False, session=session)
        cold, _ = replan(model, spec, obs, baseline=False)
        assert warm.status == cold.status == "converged"
        remaining = spec.steps - pushes
        # the re-plan's rollouts are the remaining steps only, on the planning mesh
        assert warm.commands.shape == (remaining, 3) and warm.rollouts["verification"] == 0
        np.testing.assert_allclose(warm.commands, cold.commands, atol=COMMANDS_AGREE * spec.max_step)
        assert np.hypot(*(warm.verified.lower[-1] - cold.verified.lower[-1])[:2]) <= warm.spec.tolerance
        assert within_tolerance(warm.verified.lower[-1], warm.spec)
    # built once: one calibration, one NLP, and no press re-run for the second push
    assert session.calibrations == 1 and session.nlp_builds == 1
    assert len(session.executed) == 2


def test_a_push_at_a_time_reaches_the_state_of_one_run(setting):
    model, spec, first, _ = setting
    executed = tuple(planar_commands(first.commands[:2]))
    stepped = FeRollouts(model.model(), _press(model), "t")
    for command in executed:
        stepped.advance((command,))
    at_once = FeRollouts(model.model(), _press(model), "t", after=executed)
    a, b = _start_lag(stepped), _start_lag(at_once)
    np.testing.assert_allclose(a, b, rtol=STATE_AGREE, atol=STATE_AGREE * np.abs(b).max())
    assert np.abs(a[:2]).max() > 1e-6  # a loaded state, with a lag of micrometres


def test_a_calibration_that_no_longer_predicts_the_lag_is_refitted(setting, monkeypatch):
    model, spec, first, run = setting
    obs = _observations(run, 1, len(_press(model)))
    kept = PlanSession(model, spec, verify=False)
    kept.plan(spec, baseline=False)
    kept_result, _ = replan(model, spec, obs, baseline=False, session=kept)
    assert kept.calibrations == 1 and kept.nlp_builds == 1
    monkeypatch.setattr(planner_module, "CARRY_LAG_FRACTION", 0.0)  # nothing predicts exactly
    refit = PlanSession(model, spec, verify=False)
    refit.plan(spec, baseline=False)
    refit_result, _ = replan(model, spec, obs, baseline=False, session=refit)
    assert refit.calibrations == 2 and refit.nlp_builds == 2
    assert refit_result.status == kept_result.status == "converged"
    # the refit is the cold re-plan's calibration: a naive push of the remaining steps
    cold, _ = replan(model, spec, obs, baseline=False)
    assert refit_result.params.compliance == pytest.approx(cold.params.compliance, rel=1e-9)
