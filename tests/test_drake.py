"""The FE push model in Drake (issue 40 item 3): the LeafSystem in a Diagram with an
arm (the wrist's reaction is the FE gripper force), its outputs against PushModel's
own rollouts, the moment balance against the reported moment, the AutoDiffXd
gradient against the exact Jacobian, and a MathematicalProgram plan against
``pushplan plan`` on the same scenario.  pydrake comes with the ``test`` extra
(``pushplan[drake]``), so CI runs all of it; without pydrake only the error test runs."""

import subprocess
import sys
import tomllib

import numpy as np
import pytest

from pushplan.config.plan import parse_plan
from pushplan.config.scenario import parse_scenario
from pushplan.errors import InputError
from pushplan.planning import PushModel, plan

from test_push_model import COMMANDS, SCENARIO

REACTION_REL_TOL = 1e-9
"""The wrist's reaction against the FE wrench on the block, relative to its largest entry (issue 40)."""
BALANCE_REL_TOL = 1e-6
"""The balance's M_z against the reported one, relative to the largest moment: the step's equilibrium residual."""
PLAN_SCENARIO = SCENARIO.replace('name = "tiny_rubber"', 'name = "drake_plan"').replace(
    "elements = [2, 2, 1]", "elements = [4, 4, 2]") + """
[plan]
x = 1.0e-3
y = 0.5e-3
steps = 3
max_step = 0.8e-3
tolerance = 5e-6
planning_elements = [2, 2, 1]
planning_quadrature = 2
"""


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)


def test_missing_pydrake_names_the_extra():  # runs with or without pydrake
    code = "import sys; sys.modules['pydrake'] = None\nimport pushplan.drake"
    out = _run(code)
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1] == ("ImportError: pushplan.drake needs pydrake: "
                                                  "pip install 'pushplan[drake]'")


try:
    from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
    from pydrake.solvers import MathematicalProgram
    from pydrake.multibody.tree import BodyIndex
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from pushplan.drake import (FePushSystem, add_push_constraint, add_push_cost, arm_diagram, block_wrench,
                                plan_to_target)
except ImportError:
    HAVE_DRAKE = False
else:
    HAVE_DRAKE = True
needs_drake = pytest.mark.skipif(not HAVE_DRAKE, reason="pydrake is the extra 'drake' (pip install "
                                 "'pushplan[drake]'; the test extra, so CI, installs it)")


@pytest.fixture(scope="module")
def push():
    return PushModel.from_scenario(parse_scenario(tomllib.loads(SCENARIO)))


def _wrist_reaction(plant, context) -> np.ndarray:
    """``(M, F)`` the wrist applies on the gripper at its origin, world frame."""
    wrist = plant.GetJointByName("wrist")
    F = plant.get_reaction_forces_output_port().Eval(context)[int(wrist.index())]  # on the child, in its frame
    R = plant.EvalBodyPoseInWorld(context, plant.GetBodyByName("gripper")).rotation()
    return np.concatenate([R.multiply(F.rotational()), R.multiply(F.translational())])


@needs_drake
def test_wrist_reaction_is_the_fe_gripper_force(push):
    diagram, plant, fe = arm_diagram(push, period=0.01)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    gripper = np.cumsum(COMMANDS, axis=0)  # the commands' increments as absolute gripper poses
    for k, command in enumerate(gripper):
        diagram.get_input_port(0).FixValue(context, command)
        simulator.AdvanceTo(0.01 * k + 0.015)  # two updates each: the second, unchanged, takes no FE step
    fe_context, plant_context = fe.GetMyContextFromRoot(context), plant.GetMyContextFromRoot(context)
    assert fe.held(fe_context).steps == len(COMMANDS)
    wrench = fe.GetOutputPort("wrench_on_block").Eval(fe_context)
    poses, forces = push.rollout_with_forces(COMMANDS)
    assert np.abs(wrench[3:] - forces[-1]).max() <= 1e-12 * np.abs(forces[-1]).max()  # X_WF is a translation
    assert np.abs(fe.GetOutputPort("block_pose").Eval(fe_context) - poses[-1]).max() <= 1e-15
    reaction = _wrist_reaction(plant, plant_context)
    assert np.abs(reaction - wrench).max() <= REACTION_REL_TOL * np.abs(wrench).max()
    assert np.linalg.norm(plant.GetVelocities(plant_context)) > 0  # the arm moved: the reaction is not a statics
    applied = plant.get_applied_spatial_force_input_port().Eval(plant_context)[0]
    assert np.allclose(applied.F_Bq_W.translational(), -forces[-1], rtol=1e-12, atol=0)  # the reaction's sign


def _sampled_arc(push, periods: int) -> np.ndarray:
    """Final lower-face pose of the gripper moved along a 1 rad arc of 2 mm radius while
    turning 0.05 rad, in 1 s, sampled by the system every ``1 / periods`` s."""
    t = np.linspace(0.0, 1.0, 201)
    path = np.vstack([2e-3 * np.sin(t), 2e-3 * (1 - np.cos(t)), 0.05 * t])
    builder = DiagramBuilder()
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.CubicShapePreserving(t, path)))
    fe = builder.AddSystem(FePushSystem(push, BodyIndex(0), 1.0 / periods))
    builder.Connect(source.get_output_port(), fe.get_input_port(0))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(1.0 + 1e-9)  # the update at t = 1 s is the first thing after it
    held = fe.held(fe.GetMyContextFromRoot(simulator.get_context()))
    assert held.steps == periods  # the update at t = 0 does not move
    return held.pose


@needs_drake
def test_a_moving_command_converges_as_the_period_shrinks(push):
    """The period samples the gripper's path (the friction is path-dependent): the final
    position converges at first order (12.3, 6.4, 2.7, 0.9 um from a 64-period run at
    4, 8, 16, 32 periods, measured once)."""
    poses = {n: _sampled_arc(push, n) for n in (4, 8, 16, 32)}
    d = {n: np.hypot(*(poses[n][:2] - poses[32][:2])) for n in (4, 8, 16)}
    assert d[4] > 1.5 * d[8] > 1.5 * 1.5 * d[16]
    assert d[16] < 3e-6


@needs_drake
def test_a_refused_gripper_command_is_named(push):
    diagram, _, fe = arm_diagram(push, period=0.01)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.get_input_port(0).FixValue(context, [0.05, 0.0, 0.0])  # 5 cm in one period: longer than the block
    with pytest.raises(InputError, match=r"gripper_command \[0.05, 0.0, 0.0\] at t = 0 s.*longer than the block"):
        simulator.AdvanceTo(0.005)
    assert fe.held(fe.GetMyContextFromRoot(context)).steps == 0


@needs_drake
def test_moment_balance_is_the_reported_moment(push):
    state = push.pressed.state
    for command in COMMANDS:
        state, report = push.step_report(state, command)
        wrench = block_wrench(push.model, report)
        assert abs(wrench[2] - report.gripper_force[2]) <= BALANCE_REL_TOL * np.abs(wrench[:3]).max()
        assert np.array_equal(wrench[3:], report.upper_force)
        assert np.abs(wrench[:2]).max() > 10 * abs(wrench[2])  # the tilt moments the FE report does not carry


@needs_drake
def test_autodiff_gradients_are_the_exact_jacobian(push):
    prog = MathematicalProgram()
    z = prog.NewContinuousVariables(2, 3, "z")
    scale = np.array([1e-3, 1e-3, 0.05])
    binding = add_push_constraint(prog, push, z, scale, [0, 1, 2], -np.ones(3), np.ones(3))
    w = (COMMANDS / scale).ravel()
    dz_dw = np.random.default_rng(0).normal(size=(6, 4))  # a chain rule through a map Drake would hold
    out = binding.evaluator().Eval(InitializeAutoDiff(w, dz_dw))
    jac = push.rollout_with_jacobian(COMMANDS)
    expected = jac.d_commands[-1].reshape(3, 6) * np.tile(scale, 2) @ dz_dw
    assert np.array_equal(ExtractValue(out).ravel(), jac.poses[-1])
    assert np.abs(ExtractGradient(out) - expected).max() <= 1e-12 * np.abs(expected).max()
    assert np.array_equal(binding.evaluator().Eval(w), push.rollout(COMMANDS)[-1])  # doubles: the value only
    target, weights = np.array([1e-3, 1e-3]), np.array([2e6, 3e6])
    cost = add_push_cost(prog, push, z, scale, [0, 1], target, weights)
    value = cost.evaluator().Eval(InitializeAutoDiff(w, dz_dw))
    miss = jac.poses[-1, :2] - target
    assert ExtractValue(value).item() == pytest.approx((weights * miss ** 2).sum(), rel=1e-14)
    expected = 2 * (weights * miss) @ expected[:2]
    assert np.abs(ExtractGradient(value).ravel() - expected).max() <= 1e-12 * np.abs(expected).max()


@needs_drake
def test_mathematical_program_reaches_the_target_as_pushplan_plan_does():
    scenario = parse_scenario(tomllib.loads(PLAN_SCENARIO))
    planned = plan(scenario, baseline=False)  # what `pushplan plan` runs
    ours = plan_to_target(scenario)
    assert ours.solver == "SNOPT" and ours.success and ours.reached
    tol = planned.spec.tolerance
    assert planned.status == "converged"
    assert np.hypot(*(ours.final[:2] - planned.spec.target[:2])) == ours.error <= 0.02 * tol
    assert np.hypot(*(ours.final[:2] - planned.verified.final()[:2])) <= tol  # the two plans agree
    assert np.all(np.hypot(ours.commands[:, 0], ours.commands[:, 1]) <= planned.spec.max_step * (1 + 1e-6))
    assert np.all(ours.commands[:, 2] == 0)  # no yaw target: no turn
    assert 0 < ours.rollouts <= 50


@needs_drake
def test_the_solver_stops_at_its_iteration_cap_and_says_so():
    scenario = parse_scenario(tomllib.loads(PLAN_SCENARIO))
    capped = plan_to_target(scenario, max_iterations=1)  # SNOPT needs 3 major iterations here
    assert not capped.success and not capped.reached and capped.error > parse_plan(scenario).tolerance
    assert capped.rollouts <= 5


@needs_drake
@pytest.mark.parametrize("solver", [pytest.param("IPOPT", marks=pytest.mark.slow), "NLopt"])  # IPOPT: 13 s at load 10
def test_the_other_drake_solvers_reach_the_target_too(solver):
    scenario = parse_scenario(tomllib.loads(PLAN_SCENARIO))
    ours = plan_to_target(scenario, solver=solver)
    assert ours.solver == {"IPOPT": "Ipopt", "NLopt": "NLopt"}[solver] and ours.success and ours.reached
    assert ours.error <= 0.02 * parse_plan(scenario).tolerance
    with pytest.raises(InputError, match="solver must be one of SNOPT, IPOPT, NLopt, got 'snopt'"):
        plan_to_target(scenario, solver="snopt")


@needs_drake
def test_a_solver_that_gives_up_with_nan_is_not_reached_nor_bad_input():
    # on the 2 x 2 x 1 mesh NLopt (deterministic) probes NaN commands for this target and gives up with them
    scenario = parse_scenario(tomllib.loads(PLAN_SCENARIO.replace("elements = [4, 4, 2]", "elements = [2, 2, 1]")))
    ours = plan_to_target(scenario, solver="NLopt")
    assert np.isnan(ours.commands).any() and not ours.reached and not ours.success and ours.error == np.inf
