"""The planner plugin (issue 30): PushModel's exact Jacobians against central
differences, a CasADi Opti problem that reaches a target on the FE model through
the callback, batched rollouts on a process pool, units checked at the boundary."""

import casadi
import numpy as np
import pytest

from fe_contact.stepping.derivatives import with_parameters
from pushplan.config.scenario import parse_scenario
from pushplan.errors import InputError
from pushplan.planning.push_model import PushModel

REL_TOL = 1e-6
"""Exact against central-difference derivatives, relative to the largest entry."""
TARGET_TOL = 1e-9
"""m: the Opti solution's FE pose against the target."""
SCENARIO = """
name = "tiny_rubber"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
[material]
young = 5e6
poisson = 0.45
[friction]
mu_x = 0.8
mu_y = 0.3
angle_deg = 20.0
[[load]]
dz = -3e-4
[solver]
newton_tol = 1e-13
local_tol = 1e-14
"""
COMMANDS = np.array([[1e-3, 5e-4, 0.0], [8e-4, 6e-4, 0.02]])


@pytest.fixture(scope="module")
def push():
    import tomllib
    return PushModel.from_scenario(parse_scenario(tomllib.loads(SCENARIO)))


def test_jacobian_against_central_differences(push):
    jac = push.rollout_with_jacobian(COMMANDS)
    np.testing.assert_allclose(jac.poses, push.rollout(COMMANDS), rtol=0, atol=1e-15)
    fd = np.zeros_like(jac.d_commands)
    for j in range(2):
        for c, h in enumerate((1e-8, 1e-8, 1e-7)):
            up, um = COMMANDS.copy(), COMMANDS.copy()
            up[j, c] += h
            um[j, c] -= h
            fd[:, :, j, c] = (push.rollout(up) - push.rollout(um)) / (2 * h)
    assert np.abs(fd - jac.d_commands).max() <= REL_TOL * np.abs(fd).max()
    assert np.abs(jac.d_commands[0, :, 1]).max() == 0  # no dependence on a later command


def test_parameter_jacobian_includes_the_press(push):
    jac = push.rollout_with_jacobian(COMMANDS)
    j = jac.parameters.index("mu_y")
    h = 1e-6 * push.model.friction.mu_y

    def poses(mu_y):
        return PushModel(with_parameters(push.model, mu_y=mu_y), push.press).rollout(COMMANDS)

    fd = (poses(push.model.friction.mu_y + h) - poses(push.model.friction.mu_y - h)) / (2 * h)
    assert np.abs(fd - jac.d_parameters[:, :, j]).max() <= REL_TOL * np.abs(fd).max()


def test_opti_reaches_a_target_through_the_callback(push):
    target = push.rollout(COMMANDS)[-1, :2]
    K = 2
    f = push.casadi_function(K)
    opti = casadi.Opti()
    v = opti.variable(3 * K)  # mm and 10 mrad: ipopt wants unit-sized variables
    scale = np.tile([1e-3, 1e-3, 1e-2], K)
    poses = f(v * scale)
    opti.subject_to(poses[3 * K - 3:3 * K - 1] * 1e3 == target * 1e3)
    opti.subject_to(opti.bounded(-1.5, v, 1.5))
    opti.minimize(casadi.sumsqr(v))
    opti.set_initial(v, np.tile([0.5, 0.0, 0.0], K))
    opti.solver("ipopt", {"ipopt.hessian_approximation": "limited-memory", "ipopt.print_level": 0,
                          "print_time": False})
    u = (opti.solve().value(v) * scale).reshape(K, 3)
    reached = push.rollout(u)[-1, :2]
    assert np.abs(reached - target).max() <= TARGET_TOL
    assert np.abs(u - COMMANDS).max() > 1e-5  # another, shorter plan than the one that made the target


def test_batched_rollouts_on_a_pool_equal_serial_ones(push):
    batch = [COMMANDS, 0.5 * COMMANDS, COMMANDS[::-1]]
    pooled = push.batch_rollouts(batch, processes=2)
    np.testing.assert_array_equal(pooled, np.array([push.rollout(c) for c in batch]))


@pytest.mark.parametrize("commands, match", [
    ([[1e-3, 0.0, 5.0]], r"commands\[0\].dtheta = 5 is beyond pi: commands are in rad"),
    ([[0.5, 0.0, 0.0]], r"commands\[0\]: a step of 0.5 m is longer than the block"),
    ([[1e-3, 0.0]], r"shape \(K, 3\)"),
    ([[np.nan, 0.0, 0.0]], r"commands\[0\].dx must be finite"),
])
def test_units_and_shapes_checked_at_the_boundary(push, commands, match):
    with pytest.raises(InputError, match=match):
        push.rollout(commands)


def test_the_documented_example_runs():
    import re
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "derivatives.md").read_text()
    block = re.findall(r"```python\n(.*?)```", text, re.S)[0]  # the plugin's; tests/test_docs.py runs every block
    exec(compile(block, "docs/derivatives.md", "exec"), {})


def test_a_frictional_pad_has_exact_jacobians_too():
    # the pad's pushes are differentiated like the bonded ones (fe_contact.stepping.pad_sensitivity)
    import tomllib
    text = SCENARIO.replace("[solver]", "[gripper]\nfriction = 0.5\n[solver]")
    push = PushModel.from_scenario(parse_scenario(tomllib.loads(text)))
    commands = 0.3 * COMMANDS
    jac = push.rollout_with_jacobian(commands)
    fd = np.zeros_like(jac.d_commands)
    for j in range(2):
        for c, h in enumerate((1e-8, 1e-8, 1e-7)):
            up, um = commands.copy(), commands.copy()
            up[j, c] += h
            um[j, c] -= h
            fd[:, :, j, c] = (push.rollout(up) - push.rollout(um)) / (2 * h)
    assert np.abs(fd - jac.d_commands).max() <= REL_TOL * np.abs(fd).max()


def test_step_report_is_one_step_of_a_rollout(push):
    state, report = push.step_report(push.pressed.state, COMMANDS[0])
    _, report2 = push.step_report(state, COMMANDS[1])
    poses, forces = push.rollout_with_forces(COMMANDS)
    assert np.array_equal([*report2.lower_centroid[:2], report2.lower_yaw], poses[-1])
    assert np.array_equal(report.upper_force, forces[0]) and np.array_equal(report2.upper_force, forces[1])
    assert np.array_equal(push.step(state, COMMANDS[1])[1], poses[-1])
    with pytest.raises(InputError, match=r"command must be one \(dx, dy, dtheta\), got shape \(2, 3\)"):
        push.step_report(state, COMMANDS)
