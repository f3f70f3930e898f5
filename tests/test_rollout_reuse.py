"""Issue 41 (re-plan latency): a session's planning mesh keeps the first step of its last
rollout, and executing that push (:meth:`FeRollouts.advance`) takes the kept state instead
of stepping again.  Both must be the numbers of the plain way bit for bit: the rollout
split after its first step, the advanced state and every rollout from it.  The model of
tests/test_closed_loop.py (4 x 4 x 2)."""

import tomllib

import numpy as np
import pytest

from pushplan.config import parse_scenario
from pushplan.config.commands import planar_commands
from pushplan.config.plan import press_commands
from pushplan.planning import rollouts as rollouts_module
from pushplan.planning.rollouts import FeRollouts

from test_closed_loop import MODEL

COMMANDS = np.array([[0.15e-3, 0.08e-3, 0.0], [0.12e-3, 0.05e-3, 0.0], [0.1e-3, 0.02e-3, 0.0]])
RELEASE = '[release]\nmode = "lift"\nsteps = 4\n'


def _pair(release: bool):
    scenario = parse_scenario(tomllib.loads(MODEL.format(mu_x=0.3, mu_y=0.15) + (RELEASE if release else "")))
    press = press_commands(scenario)
    return (FeRollouts(scenario.model(), press, "kept", scenario.release, keep_first=True),
            FeRollouts(scenario.model(), press, "plain", scenario.release))


def _numbers(steps) -> list[dict]:
    return [{k: v for k, v in s.to_dict().items() if k != "wall_time_s"} for s in steps]


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.lower, b.lower)
    np.testing.assert_array_equal(a.upper, b.upper)
    assert (a.rest is None) == (b.rest is None)
    if a.rest is not None:
        np.testing.assert_array_equal(a.rest, b.rest)
    assert _numbers(a.steps) == _numbers(b.steps)


@pytest.mark.parametrize("release", [False, True])
def test_an_executed_push_takes_the_kept_step_with_the_same_numbers(monkeypatch, release):
    kept, plain = _pair(release)
    _same(kept.rollout(COMMANDS), plain.rollout(COMMANDS))  # split after the first step: the same run
    steps = []
    original = rollouts_module.drive
    monkeypatch.setattr(rollouts_module, "drive", lambda *a, **k: steps.append(len(a[1])) or original(*a, **k))
    executed = planar_commands(COMMANDS[:1])
    kept.advance(executed)
    assert steps == []  # no FE step: the rollout's first one
    plain.advance(executed)
    assert steps == [1]
    a, b = kept.pressed(), plain.pressed()
    np.testing.assert_array_equal(a.state.displacement, b.state.displacement)
    assert _numbers(a.steps) == _numbers(b.steps)
    # every later rollout from the kept state (its cached tangent included) is the plain one's
    _same(kept.rollout(COMMANDS[1:]), plain.rollout(COMMANDS[1:]))
    _same(kept.rollout(COMMANDS[1:2]), plain.rollout(COMMANDS[1:2]))


def test_another_push_than_the_kept_one_is_stepped(monkeypatch):
    kept, _ = _pair(False)
    kept.rollout(COMMANDS)
    steps = []
    original = rollouts_module.drive
    monkeypatch.setattr(rollouts_module, "drive", lambda *a, **k: steps.append(len(a[1])) or original(*a, **k))
    other = COMMANDS[:1].copy()
    other[0, 0] = np.nextafter(other[0, 0], 1.0)  # one ulp off
    kept.advance(planar_commands(other))
    assert steps == [1]
    kept.rollout(COMMANDS, from_rest=True)  # from rest: not from the start state, nothing kept
    kept.advance(planar_commands(COMMANDS[1:2]))
    assert steps == [1, 3, 1]
