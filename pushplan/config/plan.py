"""The ``[plan]`` table of a planning scenario (``pushplan plan``) and its press.

The scenario's ``[[load]]`` entries are the press (``dz`` only, net compression),
applied before the planned commands; the ``[plan]`` table reads (SI units)::

    [plan]
    x = 0.9e-3                 # target lower-face centroid displacement, m
    y = 0.9e-3
    yaw_deg = 5.0              # optional target lower-face yaw (enables dtheta commands)
    steps = 4                  # K planned commands
    max_step = 0.4e-3          # bound on each command's in-plane length, m
    max_dtheta_deg = 2.0       # bound on each command's rotation (only with yaw_deg)
    tolerance = 3e-6           # final position tolerance, m (default 0.25 % of travel)
    yaw_tolerance_deg = 0.1    # final yaw tolerance (default 0.1)
    effort_weight = 1e-3       # weight of sum |u_k / bound|^2 against (error / tolerance)^2
    planning_elements = [6, 6, 2]
    planning_quadrature = 2
    max_rollouts = 6           # FE rollouts per mesh in the correction loop
    frame = "block"            # "world": x, y, yaw_deg are the MuJoCo world pose (below)
    target_state = "rest"      # "loaded": the lower face while the gripper still holds it after the
                               # last command; "rest": where it comes to rest after the scenario's
                               # [release] (default when there is one; needs one)
    robust = {level = 0.95, max_iterations = 8, monte_carlo = 50, seed = 0}
                               # settings of the robust plan (pushplan plan --identified, docs/planning.md)
    episodes = 3               # closed-loop to a rest target: at most this many grasp, push and
                               # release cycles (1 to 10; default 3)

With ``frame = "world"`` (a scenario with a ``[mujoco]`` table) ``x``, ``y`` are the
world position (m) of the lower-face centre and ``yaw_deg`` the block's world yaw;
:func:`world_to_block` turns them into the block-frame displacement the planner works
in, from the block's rest pose in the MJCF (``origin``: lower-face centre x, y and yaw
at ``qpos0``, given to :func:`parse_plan` by the caller that read the MJCF).

:func:`parse_plan` gives a :class:`PlanSpec`; ``parse_plan`` of a scenario whose
``[plan]`` is ``spec.to_table()`` gives ``spec`` back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fe_contact import Command, wrap_angle

from ..errors import InputError
from ..limits import (MAX_COUNT, MAX_EFFORT_WEIGHT, MAX_ELEMENTS, MAX_EPISODES, MAX_LENGTH, MAX_MONTE_CARLO,
                      MAX_PLAN_STEPS, MAX_ROBUST_ITERATIONS, MAX_ROLLOUTS, MIN_PLAN_STEP, MIN_TOLERANCE_LENGTH)
from .commands import MAX_TURN_DEG, degrees_exact
from .scenario import Scenario
from .validate import Table, count

PLAN_KEYS = frozenset({
    "x", "y", "yaw_deg", "steps", "max_step", "max_dtheta_deg", "tolerance", "yaw_tolerance_deg",
    "effort_weight", "planning_elements", "planning_quadrature", "max_rollouts", "frame", "target_state", "robust",
    "episodes",
})
ROBUST_KEYS = frozenset({"level", "max_iterations", "monte_carlo", "seed"})
FRAMES = ("block", "world")
TARGET_STATES = ("loaded", "rest")
REQUIRED_KEYS = frozenset({"x", "y", "steps", "max_step"})
DEFAULT_TOLERANCE_REL = 0.0025
"""Default position tolerance as a fraction of the travel distance."""
DEFAULT_YAW_TOLERANCE_DEG = 0.1
DEFAULT_EFFORT_WEIGHT = 1e-3
DEFAULT_PLANNING_ELEMENTS = (6, 6, 2)
DEFAULT_PLANNING_QUADRATURE = 2
DEFAULT_MAX_ROLLOUTS = 6
DEFAULT_EPISODES = 3
DEFAULT_ROBUST_LEVEL = 0.95
DEFAULT_ROBUST_ITERATIONS = 8
DEFAULT_MONTE_CARLO = 50


@dataclass(frozen=True)
class RobustSpec:
    """``[plan] robust``: the robust plan's settings (:mod:`pushplan.planning.robust`).

    ``level`` the probability (0, 1) of the final pose within tolerance over the identified
    distribution that the plan must reach; ``max_iterations`` the sigma-point evaluations
    of its refinement (each ``2 n + 1`` FE rollouts on the verification mesh, n identified
    parameters); ``monte_carlo`` the truths drawn for the check (0: none) and ``seed``
    their random seed.
    """

    level: float = DEFAULT_ROBUST_LEVEL
    max_iterations: int = DEFAULT_ROBUST_ITERATIONS
    monte_carlo: int = DEFAULT_MONTE_CARLO
    seed: int = 0

    def to_dict(self) -> dict:
        return {"level": self.level, "max_iterations": self.max_iterations, "monte_carlo": self.monte_carlo,
                "seed": self.seed}


def parse_robust(t: Table) -> RobustSpec:
    """``[plan] robust`` (an inline table; absent: the defaults).

    Raises
    ------
    InputError
        Unknown key or bad value, named.
    """
    r = t.table("robust", ROBUST_KEYS, default={})
    level = r.number("level", DEFAULT_ROBUST_LEVEL, positive=True)
    if not level < 1.0:
        raise InputError(f"plan.robust.level must be a probability in (0, 1), got {r.data['level']!r}")
    return RobustSpec(level=level,
                      max_iterations=r.integer("max_iterations", DEFAULT_ROBUST_ITERATIONS, minimum=1,
                                               maximum=MAX_ROBUST_ITERATIONS),
                      monte_carlo=r.integer("monte_carlo", DEFAULT_MONTE_CARLO, minimum=0, maximum=MAX_MONTE_CARLO),
                      seed=r.integer("seed", 0, minimum=0, maximum=MAX_COUNT))


STEP_SLACK = 1e-6
"""A command may exceed the step bounds by this fraction of them (:meth:`PlanSpec.check_steps`):
the planner's own commands keep their bound to its NLP's tolerance (ipopt relaxes the bound
``|u|^2 <= max_step^2`` by 1e-8 of it: a push at the bound is 5e-9 longer, measured), so
a client sending them back is not refused."""


@dataclass(frozen=True)
class PlanSpec:
    """A validated ``[plan]`` table (SI units, radians).

    ``target`` is the lower-face pose ``(x, y, yaw)`` relative to the rest pose;
    ``yaw`` is 0 and ignored when ``yaw_targeted`` is false (``max_dtheta`` too).
    """

    target: tuple[float, float, float]
    yaw_targeted: bool
    steps: int
    max_step: float
    max_dtheta: float
    tolerance: float
    yaw_tolerance: float
    effort_weight: float
    planning_elements: tuple[int, int, int]
    planning_quadrature: int
    max_rollouts: int
    target_state: str = "loaded"
    world_target: tuple[float, float, float] | None = None
    """With ``frame = "world"``: the table's world ``(x, y, yaw)`` (m, rad)."""
    world_origin: tuple[float, float, float] | None = None
    """With ``frame = "world"``: the block's rest pose ``(x, y, yaw)`` in the world."""
    robust: RobustSpec = RobustSpec()
    """``robust``: the settings of a robust plan (used with ``pushplan plan --identified``)."""
    episodes: int = DEFAULT_EPISODES
    """``closed-loop`` to a rest target: grasp, push and release cycles at most."""

    @property
    def travel(self) -> float:
        """Distance from the rest pose to the target position, m."""
        return math.hypot(self.target[0], self.target[1])

    @property
    def reachable(self) -> bool:
        """Whether the target is within K times the step bounds (:meth:`reachable_from` the start)."""
        return self.reachable_from((0.0, 0.0, 0.0))

    def reachable_from(self, origin) -> bool:
        """Whether the target is within K times the step bounds of ``origin`` (3,) (m, m,
        rad; relative to the start, :func:`~pushplan.planning.target.reach_origin`): the
        pose the block would end at without a push."""
        d = [float(t) - float(o) for t, o in zip(self.target, origin, strict=True)]
        ok = math.hypot(d[0], d[1]) <= self.steps * self.max_step
        if self.yaw_targeted:
            ok = ok and abs(d[2]) <= self.steps * self.max_dtheta
        return ok

    def step_excess(self, commands) -> tuple[int, str] | None:
        """The first row of ``commands`` (K, 3) ``(dx, dy, dtheta)`` (m, m, rad) beyond the
        step bounds and why (``"is a push of ... beyond plan.max_step = ..."``), or None: a
        row whose in-plane length exceeds ``max_step``, or whose turn exceeds ``max_dtheta``
        with a yaw target (without one: half a turn, the command codec's
        :data:`~pushplan.config.commands.MAX_TURN_DEG`), each by more than
        :data:`STEP_SLACK` of it: the bounds the planner's own commands keep, the physical
        size of one push the scenario states.  The one test of them: :meth:`check_steps`
        refuses what it finds, the Gauss-Newton correction
        (:func:`~pushplan.planning.refine.gauss_newton_commands`) steps only where it finds none."""
        for k, (dx, dy, dtheta) in enumerate(commands):
            if math.hypot(dx, dy) > self.max_step * (1 + STEP_SLACK):
                return k, (f"is a push of {math.hypot(dx, dy):.6g} m in the plane, beyond plan.max_step = "
                           f"{self.max_step:g} m (the scenario's bound on one command)")
            turn = self.max_dtheta * (1 + STEP_SLACK) if self.yaw_targeted else math.radians(MAX_TURN_DEG)
            if abs(dtheta) > turn or (not self.yaw_targeted and abs(dtheta) == turn):
                bound = (f"plan.max_dtheta_deg = {math.degrees(self.max_dtheta):g}" if self.yaw_targeted
                         else f"half a turn ({MAX_TURN_DEG:g} deg, exclusive)")
                return k, f"turns {math.degrees(dtheta):.6g} deg, beyond {bound} (the scenario's bound on one command)"
        return None

    def check_steps(self, commands, key: str, name=None) -> None:
        """Refuse commands (K, 3) ``(dx, dy, dtheta)`` (m, m, rad) beyond the step bounds
        (:meth:`step_excess`).  ``name(k)`` names row k and its value in the message
        (default ``key[k]: [dx, dy, dtheta]``).

        Raises
        ------
        InputError
            Naming the row, its value and the bound it exceeds.
        """
        found = self.step_excess(commands)
        if found is None:
            return
        k, why = found
        label = name(k) if name else f"{key}[{k}]: {[float(v) for v in commands[k]]}"
        raise InputError(f"{label} {why}")

    def to_dict(self) -> dict:
        """The ``plan.json`` form: every setting (angles in degrees, None where unused) and the travel."""
        return {
            "x": self.target[0], "y": self.target[1],
            "yaw_deg": math.degrees(self.target[2]) if self.yaw_targeted else None,
            "steps": self.steps, "max_step": self.max_step,
            "max_dtheta_deg": math.degrees(self.max_dtheta) if self.yaw_targeted else None,
            "tolerance": self.tolerance, "yaw_tolerance_deg": math.degrees(self.yaw_tolerance),
            "effort_weight": self.effort_weight, "planning_elements": list(self.planning_elements),
            "planning_quadrature": self.planning_quadrature, "max_rollouts": self.max_rollouts,
            "travel": self.travel, "target_state": self.target_state, "episodes": self.episodes,
            "robust": self.robust.to_dict(), "frame": "block" if self.world_origin is None else "world",
            **({} if self.world_origin is None else {"world": {
                "x": self.world_target[0], "y": self.world_target[1],
                "yaw_deg": math.degrees(self.world_target[2]) if self.yaw_targeted else None,
                "origin": {"x": self.world_origin[0], "y": self.world_origin[1],
                           "yaw_deg": math.degrees(self.world_origin[2])}}}),
        }

    def to_table(self) -> dict:
        """The ``[plan]`` table that :func:`parse_plan` reads back as this spec (defaults written out)."""
        table = {"x": self.target[0], "y": self.target[1], "steps": self.steps, "max_step": self.max_step,
                 "tolerance": self.tolerance, "yaw_tolerance_deg": degrees_exact(self.yaw_tolerance),
                 "effort_weight": self.effort_weight, "planning_elements": list(self.planning_elements),
                 "planning_quadrature": self.planning_quadrature, "max_rollouts": self.max_rollouts,
                 "target_state": self.target_state, "robust": self.robust.to_dict(), "episodes": self.episodes}
        if self.yaw_targeted:
            table.update(yaw_deg=degrees_exact(self.target[2]), max_dtheta_deg=degrees_exact(self.max_dtheta))
        if self.world_target is not None:
            table.update(frame="world", x=self.world_target[0], y=self.world_target[1])
            if self.yaw_targeted:
                table.update(yaw_deg=degrees_exact(self.world_target[2]))
        return table


def world_to_block(pose, origin) -> tuple[float, float, float]:
    """Block-frame target ``(x, y, yaw)`` (displacement from rest, m, rad) of a world pose.

    Parameters
    ----------
    pose : (3,)
        World position ``x, y`` (m) of the lower-face centre and world yaw (rad).
    origin : (3,)
        The block's rest pose in the world: lower-face centre ``x0, y0`` and yaw ``a0``.

    Returns
    -------
    tuple
        ``R(-a0) (x - x0, y - y0)`` and ``yaw - a0`` wrapped to (-pi, pi].
    """
    x0, y0, a0 = (float(v) for v in origin)
    c, s = math.cos(a0), math.sin(a0)
    dx, dy = float(pose[0]) - x0, float(pose[1]) - y0
    return c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(float(pose[2]) - a0))


def block_to_world(pose, origin) -> tuple[float, float, float]:
    """World pose of a block-frame lower-face pose (the inverse of :func:`world_to_block`)."""
    x0, y0, a0 = (float(v) for v in origin)
    c, s = math.cos(a0), math.sin(a0)
    x, y = float(pose[0]), float(pose[1])
    return x0 + c * x - s * y, y0 + s * x + c * y, float(wrap_angle(float(pose[2]) + a0))


def press_commands(scenario: Scenario) -> tuple[Command, ...]:
    """The scenario's ``[[load]]`` entries, checked to be a press (``dz`` only, net compression).

    Raises
    ------
    InputError
    """
    cmds = scenario.commands
    if not cmds:
        raise InputError("a planning scenario needs [[load]] entries pressing the block (dz < 0)")
    for i, c in enumerate(cmds):
        if c.dx or c.dy or c.dtheta:
            raise InputError(f"load[{i}] moves the upper face in the plane; the [[load]] entries of a "
                             "planning scenario are the press (dz only)")
    if sum(c.dz for c in cmds) >= 0:
        raise InputError("the [[load]] entries must press the block (total dz < 0)")
    return cmds


def _planning_elements(t: Table) -> tuple:
    """``[plan] planning_elements``: a mesh of at most :data:`~pushplan.limits.MAX_ELEMENTS`
    elements (its memory is checked by the command, :func:`~pushplan.config.budget.check_memory`)."""
    elements = t.triple("planning_elements", count, list(DEFAULT_PLANNING_ELEMENTS))
    if math.prod(elements) > MAX_ELEMENTS:
        raise InputError(f"plan.planning_elements must give at most {MAX_ELEMENTS} elements, got {list(elements)}")
    return elements


def _max_dtheta(t: Table, yaw_targeted: bool) -> float:
    """``[plan] max_dtheta_deg`` in radians: required with ``yaw_deg``, refused without (0)."""
    if yaw_targeted:
        if "max_dtheta_deg" not in t:
            raise InputError("missing key plan.max_dtheta_deg (needed with plan.yaw_deg)")
        return math.radians(t.number("max_dtheta_deg", positive=True, hi=180.0))
    if "max_dtheta_deg" in t:
        raise InputError("plan.max_dtheta_deg is only used with plan.yaw_deg (rotation commands)")
    return 0.0


def _frame(t: Table, target: tuple, yaw_targeted: bool, world_origin) -> tuple[tuple, tuple | None, tuple | None]:
    """``(block-frame target, world_target, world_origin)`` of ``[plan] frame`` (the
    world ones None for ``frame = "block"``)."""
    if t.choice("frame", FRAMES, "block") != "world":
        return target, None, None
    if world_origin is None:
        raise InputError("plan.frame = 'world' needs the block's world pose: a [mujoco] table naming the "
                         "MJCF scene (pushplan plan reads it)")
    world_origin = tuple(float(v) for v in world_origin)
    x, y, block_yaw = world_to_block(target, world_origin)
    return (x, y, block_yaw if yaw_targeted else 0.0), target, world_origin


def _tolerance(t: Table, travel: float) -> float:
    """``[plan] tolerance`` (m); default :data:`DEFAULT_TOLERANCE_REL` of the travel."""
    if "tolerance" in t:
        return t.number("tolerance", minimum=MIN_TOLERANCE_LENGTH, maximum=MAX_LENGTH)
    if travel > 0:
        return DEFAULT_TOLERANCE_REL * travel
    raise InputError("plan.tolerance is required when the target position is the start (x = y = 0)")


def _target_state(t: Table, scenario: Scenario) -> str:
    """``[plan] target_state``: ``"rest"`` by default with a ``[release]`` table (and needs one)."""
    target_state = t.choice("target_state", TARGET_STATES, "rest" if scenario.release else "loaded")
    if target_state == "rest" and scenario.release is None:
        raise InputError('plan.target_state = "rest" needs a [release] table (how the gripper lets go)')
    return target_state


def _target(t: Table) -> tuple[tuple[float, float, float], bool]:
    """``[plan] x, y, yaw_deg``: the target ``(x, y, yaw)`` (m, m, rad) in the table's frame
    and whether the yaw is targeted."""
    x, y = t.number("x", minimum=-MAX_LENGTH, maximum=MAX_LENGTH), t.number("y", minimum=-MAX_LENGTH, maximum=MAX_LENGTH)
    yaw_targeted = "yaw_deg" in t
    yaw = math.radians(t.number("yaw_deg", lo=-180.0, hi=180.0)) if yaw_targeted else 0.0
    return (x, y, yaw), yaw_targeted


def _max_step(t: Table) -> float:
    """``[plan] max_step`` (m), at least :data:`~pushplan.limits.MIN_PLAN_STEP`."""
    max_step = t.number("max_step", positive=True, maximum=MAX_LENGTH)
    if max_step < MIN_PLAN_STEP:
        raise InputError(f"plan.max_step must be >= {MIN_PLAN_STEP} m (a smaller push is below the solver's "
                         f"tolerance), got {t.data['max_step']!r}")
    return max_step


def parse_plan(scenario: Scenario, world_origin=None) -> PlanSpec:
    """Validate the scenario's ``[plan]`` table and its press.

    Parameters
    ----------
    world_origin : (3,), optional
        The block's rest pose in the world (lower-face centre x, y in m, yaw in rad),
        needed by ``frame = "world"``.

    Raises
    ------
    InputError
        Missing table, unknown key or bad value (named), a ``[[load]]`` that is not
        a press (``dz`` only, net compression), friction missing in a direction, or
        ``frame = "world"`` without ``world_origin``.
    """
    if "plan" not in scenario.extra:
        raise InputError(f"scenario {scenario.name!r} has no [plan] table")
    t = Table(scenario.extra["plan"], "plan", PLAN_KEYS, required=REQUIRED_KEYS)
    press_commands(scenario)
    if scenario.mu_x <= 0 or scenario.mu_y <= 0:
        raise InputError(f"planning needs friction in both directions, got mu_x = {scenario.mu_x}, "
                         f"mu_y = {scenario.mu_y}")
    target, yaw_targeted = _target(t)
    steps = t.integer("steps", minimum=1, maximum=MAX_PLAN_STEPS)
    max_step = _max_step(t)
    max_dtheta = _max_dtheta(t, yaw_targeted)
    target, world_target, world_origin = _frame(t, target, yaw_targeted, world_origin)
    tolerance = _tolerance(t, math.hypot(target[0], target[1]))
    target_state = _target_state(t, scenario)
    return PlanSpec(
        target=target, yaw_targeted=yaw_targeted, steps=steps, max_step=max_step, max_dtheta=max_dtheta,
        tolerance=tolerance,
        yaw_tolerance=math.radians(t.number("yaw_tolerance_deg", DEFAULT_YAW_TOLERANCE_DEG, positive=True, hi=180.0)),
        effort_weight=t.number("effort_weight", DEFAULT_EFFORT_WEIGHT, nonneg=True, maximum=MAX_EFFORT_WEIGHT),
        planning_elements=_planning_elements(t),
        planning_quadrature=t.integer("planning_quadrature", DEFAULT_PLANNING_QUADRATURE, minimum=2, maximum=3),
        max_rollouts=t.integer("max_rollouts", DEFAULT_MAX_ROLLOUTS, minimum=1, maximum=MAX_ROLLOUTS),
        world_target=world_target, world_origin=world_origin, target_state=target_state, robust=parse_robust(t),
        episodes=t.integer("episodes", DEFAULT_EPISODES, minimum=1, maximum=MAX_EPISODES),
    )
