"""Sampling MPC on the FE model (issue 40 item 2): the judo-shaped backend's
contract (shapes, the held state, x0 refused when it is not the held pose) and a
receding-horizon CEM that reaches a target the FE model can reach."""

import tomllib

import numpy as np
import pytest

from pushplan.config.scenario import parse_scenario
from pushplan.errors import InputError
from pushplan.planning.push_model import PushModel
from pushplan.planning.sampling import FeRolloutBackend, cem_mpc

from test_push_model import COMMANDS, SCENARIO

TOLERANCE = 1e-5
"""m: the CEM's final lower-face position against the target (0.5 % of its 2 mm travel)."""


@pytest.fixture(scope="module")
def push():
    with PushModel.from_scenario(parse_scenario(tomllib.loads(SCENARIO))) as push:
        yield push


def test_the_backend_keeps_judos_signature_and_holds_the_fe_state(push):
    backend = FeRolloutBackend(push, 3, processes=2)
    controls = COMMANDS[None] * np.array([1.0, 0.5, 0.8])[:, None, None]
    states, sensors, policy = backend.rollout(np.tile(backend.pose, (3, 1)), controls)
    assert states.shape == sensors.shape == (3, 2, 3) and policy is None
    assert np.abs(states[1] - push.rollout(controls[1])).max() <= 1e-12
    assert sensors[0, -1, 0] > 0  # the gripper pushes the block along +x
    backend.advance(COMMANDS[0])
    after, _, _ = backend.rollout(backend.pose, controls[:, 1:])
    assert np.abs(after[0, 0] - states[0, 1]).max() <= 1e-12  # one step executed, then the rest rolled out
    with pytest.raises(InputError, match="x0 must be the held FE state's pose"):
        backend.rollout(np.zeros(3), controls)


def test_cem_reaches_a_reachable_target(push):
    target = push.rollout(COMMANDS)[-1, :2]
    result = cem_mpc(FeRolloutBackend(push, 12, processes=2), target, 2, max_step=1.5e-3, tolerance=TOLERANCE,
                     iterations=12, elites=4)
    assert result.reached and result.error <= TOLERANCE
    assert np.abs(push.rollout(result.commands)[-1, :2] - target).max() <= TOLERANCE  # the executed plan, again
    assert result.rollouts == 12 * result.iterations
