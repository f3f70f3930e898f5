"""The FE rollout in a Drake ``MathematicalProgram``: a constraint on (or a cost of)
the final lower-face pose with its exact gradient through ``AutoDiffXd``, and a plan to
a scenario's ``[plan]`` target solved by a Drake solver.

Chain rule at the boundary: Drake evaluates a constraint on ``AutoDiffXd`` variables
``z`` carrying ``dz/dw`` (its own decision variables ``w``); the rollout gives the
poses ``p(u)`` and the exact ``dp/du`` (:meth:`PushModel.rollout_with_jacobian`), so

    value = p(u(z)),     gradient = dp/du · du/dz · dz/dw

with ``u = s * z`` (``s`` the command scale, m and rad).  Each evaluation costs one FE
rollout with its Jacobian (a repeated point from the press is answered from the kept
result, so a solver that asks for the value and then the gradient pays once).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydrake.autodiffutils import ExtractGradient, ExtractValue, InitializeAutoDiff
from pydrake.solvers import IpoptSolver, MathematicalProgram, NloptSolver, SnoptSolver, SolverOptions

from ..config.plan import PlanSpec, parse_plan
from ..config.scenario import Scenario
from ..errors import InputError
from ..planning.push_model import PushModel
from ..planning.target import naive_commands, pose_error, within_tolerance

SOLVERS = (SnoptSolver, IpoptSolver, NloptSolver)
"""Tried in this order: the first available solves."""
MAX_ITERATIONS = 30
"""Default cap on the solver's iterations (SNOPT spent 6 FE rollouts on the test's and the benchmark's plans)."""


def _components(spec: PlanSpec) -> list[int]:
    return [0, 1, 2] if spec.yaw_targeted else [0, 1]


def _final_pose(push: PushModel, K: int, scale, components):
    """``w -> pose[-1, components]`` of the FE rollout of ``u = scale * w`` (K, 3), on
    doubles (a rollout) or on ``AutoDiffXd`` (the chain rule of the module docstring)."""
    scale, comps = np.asarray(scale, float), list(components)

    def final_pose(w):
        values = ExtractValue(w).ravel() if w.dtype == object else np.asarray(w, float)
        if not np.isfinite(values).all():  # a solver probing: "cannot evaluate here", not bad input
            nan = np.full(len(comps), np.nan)
            return nan if w.dtype != object else InitializeAutoDiff(nan, np.full((len(comps), w.size), np.nan)).ravel()
        if w.dtype != object:  # plain doubles: the value only
            return push.rollout(values.reshape(K, 3) * scale)[-1, comps]
        dz_dw = ExtractGradient(w)
        jac = push.rollout_with_jacobian(values.reshape(K, 3) * scale)
        dp_du = jac.d_commands[-1, comps].reshape(len(comps), 3 * K)
        gradient = dp_du * np.tile(scale, K) @ dz_dw
        return InitializeAutoDiff(jac.poses[-1, comps], gradient).ravel()

    return final_pose


def add_push_constraint(prog: MathematicalProgram, push: PushModel, z, scale, components, lower, upper):
    """Constrain the final lower-face pose of the FE rollout of the commands
    ``u = scale * z`` (``z`` (K, 3) decision variables, ``scale`` (3,) m and rad) from
    the press: ``lower <= pose[-1, components] <= upper`` (m, rad), with the exact
    gradient.  Returns the ``Binding``."""
    z = np.asarray(z)
    return prog.AddConstraint(_final_pose(push, z.shape[0], scale, components), np.asarray(lower, float),
                              np.asarray(upper, float), z.ravel(), description="fe_final_pose")


def add_push_cost(prog: MathematicalProgram, push: PushModel, z, scale, components, target, weights):
    """Add the cost ``sum_i weights[i] (pose[-1, components[i]] - target[i])^2`` of the
    FE rollout of ``u = scale * z`` (as :func:`add_push_constraint`; ``target`` m and
    rad, ``weights`` per m^2 or rad^2), with the exact gradient.  Returns the ``Binding``."""
    z = np.asarray(z)
    pose = _final_pose(push, z.shape[0], scale, components)
    target, weights = np.asarray(target, float), np.asarray(weights, float)

    def cost(w):
        miss = pose(w) - target
        return (weights * miss * miss).sum()

    return prog.AddCost(cost, z.ravel(), description="fe_final_miss")


@dataclass(frozen=True)
class DrakePlan:
    """A plan solved by a Drake solver on the FE model.

    Attributes
    ----------
    commands : ndarray, shape (K, 3)
        ``(dx, dy, dtheta)``, m and rad.
    final : ndarray, shape (3,)
        The FE rollout's final lower-face pose, m and rad.
    error : float
        m, its distance from the target position.
    reached : bool
        Whether the final pose is within the plan's tolerances (checked, not the
        solver's word).
    solver : str
    success : bool
        The solver's own verdict.
    rollouts : int
        FE rollouts the solve evaluated.
    wall_time : float
        s.
    """

    commands: np.ndarray
    final: np.ndarray
    error: float
    reached: bool
    solver: str
    success: bool
    rollouts: int
    wall_time: float


def _solver(max_iterations: int, name: str | None = None):
    """The first available of :data:`SOLVERS` (or the one ``name``d: ``"SNOPT"``,
    ``"IPOPT"``, ``"NLopt"``) and its options capping the iterations (SNOPT's major
    iterations, IPOPT's, NLopt's evaluations)."""
    names = {"SNOPT": SnoptSolver, "IPOPT": IpoptSolver, "NLopt": NloptSolver}
    if name is not None and name not in names:
        raise InputError(f"solver must be one of {', '.join(names)}, got {name!r}")
    for cls in SOLVERS if name is None else (names[name],):
        solver = cls()
        if solver.available() and solver.enabled():
            options = SolverOptions()
            name = {SnoptSolver: "Major iterations limit", IpoptSolver: "max_iter",
                    NloptSolver: NloptSolver.MaxEvalName()}[cls]
            options.SetOption(solver.solver_id(), name, int(max_iterations))
            return solver, options
    raise RuntimeError(f"no {name or 'nonlinear solver (SNOPT, IPOPT or NLopt)'} in this pydrake")


def plan_to_target(scenario: Scenario, spec: PlanSpec | None = None, push: PushModel | None = None,
                   max_iterations: int = MAX_ITERATIONS, solver: str | None = None) -> DrakePlan:
    """Plan ``spec`` (default the scenario's ``[plan]``) as a ``MathematicalProgram``:
    least effort ``sum |u / s|^2`` subject to the FE rollout's final pose at the
    target (within a hundredth of the tolerances) and each step within ``max_step``
    (and ``max_dtheta``, or no turn without a yaw target), on the scenario's own mesh
    (``push``, default built from it: the mesh ``pushplan plan`` verifies on).  The
    solver (``solver``, default the first available of :data:`SOLVERS`) starts from the
    naive commands; its iterations are capped at ``max_iterations`` (each costs one or a
    few FE rollouts with their Jacobians)."""
    spec = spec or parse_plan(scenario)
    push = push or PushModel.from_scenario(scenario)
    K, comps = spec.steps, _components(spec)
    scale = np.array([spec.max_step, spec.max_step, spec.max_dtheta if spec.yaw_targeted else 1.0])
    prog = MathematicalProgram()
    z = prog.NewContinuousVariables(K, 3, "z")
    prog.AddQuadraticCost(np.eye(3 * K), np.zeros(3 * K), z.ravel(), is_convex=True)
    for k in range(K):
        prog.AddConstraint(z[k, 0] ** 2 + z[k, 1] ** 2 <= 1.0)
        prog.AddBoundingBoxConstraint(*((-1.0, 1.0) if spec.yaw_targeted else (0.0, 0.0)), z[k, 2])
    target = np.array(spec.target)[comps]
    slack = 0.01 * np.array([spec.tolerance, spec.tolerance, spec.yaw_tolerance])[comps]
    add_push_constraint(prog, push, z, scale, comps, target - slack, target + slack)
    prog.SetInitialGuess(z, naive_commands(spec) / scale)
    (nlp, options), before, t0 = _solver(max_iterations, solver), push.rollouts_run, time.perf_counter()
    result = nlp.Solve(prog, None, options)
    commands = result.GetSolution(z) * scale
    if not np.isfinite(commands).all():  # a solver that gave up with NaN (NLopt can)
        final = np.full(3, np.nan)
        return DrakePlan(commands, final, np.inf, False, result.get_solver_id().name(), False,
                         push.rollouts_run - before, time.perf_counter() - t0)
    final = push.rollout(commands)[-1]
    return DrakePlan(commands, final, pose_error(final, spec)[0], within_tolerance(final, spec),
                     result.get_solver_id().name(), result.is_success(), push.rollouts_run - before - 1,
                     time.perf_counter() - t0)
