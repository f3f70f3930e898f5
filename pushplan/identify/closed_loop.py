"""The closed loop: execute one planned push on the real block (here a *truth* FE
model: the same block on a surface with other friction), observe its pose and force,
re-identify the friction (and Young's modulus) if asked, re-plan the remaining pushes
from the observed state (:mod:`pushplan.planning.replan`), repeat.  The open-loop
baseline executes the first plan unchanged on the same truth.

Each re-plan aims at ``target - b``, with ``b`` (m, m, rad) the truth's pose after the
last push less the pose the plan behind it expected: the error of the model on the
truth is taken to persist from one push to the next (modifier adaptation, here on the
measured block), within a quarter of the tolerances (:data:`REPLAN_TOLERANCE`).  A
rest target is scored on the truth's own release, and its ``b`` is what the loaded
discrepancy leaves after the spring-back (:func:`modifier`).  The re-identification in the loop
skips the refined-mesh and profile checks of :mod:`.uncertainty` (only its estimates
are used; the chi-square rule stays).

Observations are the truth run's exact poses and forces (no noise is added); the
identification weights them with the stated noise model.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from fe_contact import Command, Model, State, StepReport

from ..config.commands import command_to_dict, planar_commands
from ..config.plan import PlanSpec, press_commands
from ..config.scenario import Scenario
from ..errors import InputError, SolverFailure
from ..planning import plan
from ..planning.planner import PlanSession
from ..planning.replan import replan
from ..planning.target import pose_error, within_tolerance
from ..run import StepSummary, drive
from ..run.observations import observations_from_steps
from .episodes import Episode, episode_spec, pose_json, regrasp, relative_summary, rest_shift
from .fit import identify
from .noise import NoiseModel

LOOP_FIT = ("mu_x", "mu_y", "angle_deg", "young")
"""Parameters re-identified in the loop: the stiffness too, since a real block's (and a finer
mesh's) differs from the model's and sets the lag the plan must anticipate."""


class TruthFailure(SolverFailure):
    """An FE step of the truth model failed."""


class LoopError(RuntimeError):
    """A value computed inside the loop was refused as if it were input: a bug (exit 1
    with its traceback), never the bad-input exit, since the inputs were checked before
    the loop started."""


@dataclass
class Truth:
    """The truth model's run so far (press, then each executed push)."""

    model: Model
    state: State
    reports: list[StepReport] = field(default_factory=list)
    steps: list[StepSummary] = field(default_factory=list)
    last: tuple = (None, ())  # the state before the last commands, and those commands
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The world pose (x, y, yaw) its episode started from: ``steps`` hold poses relative to it."""
    rest: np.ndarray | None = None
    """The rest pose after :meth:`let_go`, relative to ``origin``."""

    def execute(self, commands) -> None:
        self.last = (self.state, tuple(commands))
        run = drive(self.model, tuple(commands), self.state)
        if not run.completed:
            f = run.summary.failure
            raise TruthFailure(f"truth FE step {f.step} failed ({f.status}): {f.message}")
        self.state = run.state
        self.reports += run.reports
        self.steps += [relative_summary(s, self.origin) for s in run.summary.steps]

    def let_go(self, release) -> np.ndarray:
        """Release the block (the last commands re-run with ``release``, as in
        :meth:`rest_pose`) and keep its rest state; returns the observed rest pose
        relative to ``origin`` (m, rad)."""
        start, commands = self.last
        run = drive(self.model, commands, start, release=release)
        if not run.completed or run.summary.rest is None:
            f = run.summary.failure
            raise TruthFailure(f"truth release failed at step {f.step} ({f.status}): {f.message}")
        self.state = run.state
        r = run.summary.rest
        self.rest = np.array([r.lower_centroid[0], r.lower_centroid[1], r.lower_yaw]) - self.origin
        return self.rest

    def regrasped(self, press) -> "Truth":
        """The truth of the next episode: the gripper grasps the block where it rests
        (:func:`~pushplan.identify.episodes.regrasp`) and applies ``press``; its poses
        relative to the rest pose."""
        origin = self.origin + self.rest
        state, grasp = regrasp(self.model, self.state)
        run = drive(self.model, grasp + tuple(press), state)
        if not run.completed:
            f = run.summary.failure
            raise TruthFailure(f"truth re-grasp failed at step {f.step} ({f.status}): {f.message}")
        t = Truth(self.model, run.state, list(run.reports[len(grasp):]), origin=origin)
        t.steps = [relative_summary(s, origin) for s in run.summary.steps[len(grasp):]]
        return t

    def rest_pose(self, release) -> np.ndarray:
        """The lower-face pose ``(x, y, yaw)`` (m, rad) at rest after ``release`` from the
        current state (the state itself is kept: the truth can go on).  The last commands
        are re-run with the release, as ``drive`` schedules a release from the last step's
        report (the same steps, so the same loaded state)."""
        start, commands = self.last
        run = drive(self.model, commands, start, release=release)
        if not run.completed or run.summary.rest is None:
            f = run.summary.failure
            raise TruthFailure(f"truth release failed at step {f.step} ({f.status}): {f.message}")
        r = run.summary.rest
        return np.array([r.lower_centroid[0], r.lower_centroid[1], r.lower_yaw])

    @property
    def pose(self) -> np.ndarray:
        s = self.steps[-1]
        return np.array([s.lower_centroid[0], s.lower_centroid[1], s.lower_yaw])


@dataclass(frozen=True)
class Iteration:
    """One push of the closed loop: the command executed, the pose observed after it,
    the friction the plan behind it used and, with identification, the estimates."""

    step: int
    command: Command
    observed: np.ndarray
    friction: dict
    plan_status: str
    plan_message: str  # why the plan behind the push has its status (the bound or tolerance it misses)
    plan_fe_rollouts: int
    identified: dict | None
    wall_time: float
    planned: np.ndarray  # (n, 3) lower-face path of the plan behind the push, from rest (m, rad)

    def to_dict(self) -> dict:
        x, y, yaw = (float(v) for v in self.observed)
        return {"step": self.step, "command": command_to_dict(self.command), "observed_pose": [x, y, math.degrees(yaw)],
                "planned_path": [_pose_json(p) for p in self.planned],
                "planned_with": self.friction, "plan_status": self.plan_status,
                "plan_message": self.plan_message, "plan_fe_rollouts": self.plan_fe_rollouts, "identified": self.identified, "wall_time_s": self.wall_time}


def _friction(sc: Scenario) -> dict:
    return {"mu_x": sc.mu_x, "mu_y": sc.mu_y, "angle_deg": sc.angle_deg}


def _error(pose, spec: PlanSpec) -> dict:
    pos, yaw = pose_error(pose, spec)
    return {"position": pos, "yaw_deg": math.degrees(yaw) if spec.yaw_targeted else None,
            "within_tolerance": within_tolerance(pose, spec)}


def _identified(result) -> dict:
    return {k: {"estimate": float(v), "sigma": float(s) if math.isfinite(s) else None, "identifiable": f}
            for k, v, s, f in zip(result.names, result.estimate, result.sigma, result.identifiable, strict=True)} | {
        "fe_rollouts": result.fe_rollouts}


def _new_truth(truth_scenario: Scenario, press) -> Truth:
    model = truth_scenario.model()
    t = Truth(model, None)
    run = drive(model, press)
    if not run.completed:
        raise TruthFailure(f"truth FE press failed: {run.summary.failure.message}")
    t.state, t.reports, t.steps = run.state, list(run.reports), list(run.summary.steps)
    return t


REPLAN_TOLERANCE = 0.25
"""Re-plans aim within this fraction of the tolerances: the rest is left to what the
model does not predict of the truth's next push."""


def modifier(spec: PlanSpec, bias: np.ndarray, drift: np.ndarray, springback: np.ndarray) -> np.ndarray:
    """The shift (3,) (m, m, rad) of a re-plan's target that makes the truth end on it.

    A re-plan aims at ``target - shift`` relative to the observed (loaded) pose ``p_t``
    from the model's state ``p_m``; ``drift = p_t - p_m`` is the sum of the pushes'
    errors, ``bias`` the last one's (taken to persist, modifier adaptation on the
    truth).  A loaded target: ``shift = bias``.  A rest target ``R = p + s (u - p)``
    (``s``, (3,), the spring-back fractions of the plan's calibration,
    :class:`~pushplan.planning.springback.Springback`): the truth rests ``(1 - s)``
    of its loaded discrepancy away from the model, so ``shift = (1 - s) bias - s
    drift``; with a bonded lift (``s = 1``) the rest is the commanded pose and the
    loaded discrepancy must be taken back out, not added."""
    if spec.target_state != "rest":
        return bias
    s = np.asarray(springback, float)
    return (1.0 - s) * bias - s * drift


def shifted_spec(spec: PlanSpec, shift: np.ndarray) -> PlanSpec:
    """``spec`` aiming at ``target - shift`` (:func:`modifier`), within
    :data:`REPLAN_TOLERANCE` of the tolerances."""
    mask = np.array([1.0, 1.0, float(spec.yaw_targeted)])
    return dataclasses.replace(spec, target=tuple(float(v) for v in np.array(spec.target) - mask * shift),
                               tolerance=REPLAN_TOLERANCE * spec.tolerance,
                               yaw_tolerance=REPLAN_TOLERANCE * spec.yaw_tolerance)


def _step(model_sc, spec, truth, k, first, use_identify, noise, log, bias, shift, session):
    """Plan (or re-plan) with the current model and execute the next push on the truth
    (re-plans in the warm ``session`` unless identification changes the model)."""
    identified = None
    if k == 0:
        result = first
    else:
        obs = observations_from_steps(truth.steps)
        if use_identify:
            est = identify(model_sc, obs, noise, LOOP_FIT, model_error=False)
            identified = _identified(est)
            model_sc = est.scenario(model_sc)
            if log:
                log(f"step {k + 1}: identified " + ", ".join(f"{n} = {v:.5g}" for n, v in zip(est.names, est.estimate, strict=True)))
        # the loop never reads the naive rollout: no baseline
        # warm in the session; cold with identification (another model each push)
        result, _ = replan(model_sc, shifted_spec(spec, shift), obs, baseline=False, session=session)
    command = planar_commands(result.commands[:1])[0]
    planned = result.verified.lower + (truth.pose if k > 0 else 0.0)  # a re-plan's poses are relative
    planned[1:] += bias  # what the plan expects of the truth
    truth.execute([command])
    return model_sc, result, command, identified, planned


def _final(truth: Truth, spec: PlanSpec, release) -> np.ndarray:
    """The pose scored against the target: the truth's rest pose after its release for a
    rest target, else its loaded pose."""
    return truth.rest_pose(release) if spec.target_state == "rest" else truth.pose


def _pushes(model_sc, spec, truth, first, use_identify, noise, log, warm, label=""):
    """Execute ``first``'s pushes one at a time on ``truth``, re-planning after each
    (:func:`modifier`); returns the model planned with last and the iterations."""
    # the warm planner of the re-plans, on the planning mesh (the bias takes up its error too)
    session = PlanSession(model_sc, spec, verify=False) if warm and not use_identify else None
    if session is not None:
        session.follow(first)
    iterations, current, bias, drift = [], model_sc, np.zeros(3), np.zeros(3)
    springback = first.springback.fractions  # of the latest plan's calibration (re-identified models' too)
    for k in range(spec.steps):
        t0 = time.perf_counter()
        try:
            current, result, command, identified, planned = _step(current, spec, truth, k, first, use_identify,
                                                                  noise, log, bias,
                                                                  modifier(spec, bias, drift, springback),
                                                                  session)
        except InputError as e:
            raise LoopError(f"closed loop {label}step {k + 1}: {e}") from e
        bias = truth.pose - planned[1] + bias  # planned[1] holds the old bias
        # the model's loaded discrepancy from the truth; an identified model is fitted to the
        # observed poses, so its own is taken as none
        drift = np.zeros(3) if use_identify else drift + bias
        springback = result.springback.fractions
        iterations.append(Iteration(k + 1, command, truth.pose, _friction(current), result.status,
                                    result.message, sum(result.rollouts.values()), identified, time.perf_counter() - t0, planned))
        if log:
            log(f"{label}step {k + 1}: observed ({truth.pose[0] * 1e3:.5f}, {truth.pose[1] * 1e3:.5f}) mm, "
                f"error {pose_error(truth.pose, spec)[0] * 1e6:.3f} um")
    return current, iterations


def _world(iterations, origin) -> tuple:
    """``iterations`` with their poses moved from an episode's frame to the world's."""
    return tuple(dataclasses.replace(it, observed=it.observed + origin, planned=it.planned + origin)
                 for it in iterations)


def _episodes(current, spec, truth, first, iterations, release, press, options, t_start):
    """The first episode's release and, while its rest pose is outside the tolerance,
    further episodes (:mod:`.episodes`), ``spec.episodes`` in all at most; returns the
    model planned with last, the episodes and the last episode's truth."""
    use_identify, noise, log, warm = options
    truth.let_go(release)
    episodes = [Episode(1, np.zeros(3), np.array(spec.target), tuple(iterations), truth.pose, truth.rest,
                        _error(truth.rest, spec), 0, time.perf_counter() - t_start)]
    observed, aimed = [], []
    while len(episodes) < spec.episodes and not within_tolerance(episodes[-1].rest, spec):
        t0, index = time.perf_counter(), len(episodes) + 1
        origin = episodes[-1].rest
        spec_e = episode_spec(spec, origin, rest_shift(observed, aimed))
        if log:
            log(f"episode {index}: rest {pose_error(origin, spec)[0] * 1e6:.3f} um off, re-grasp")
        truth = truth.regrasped(press)
        first_e = plan(current, spec_e, baseline=False)
        current, its = _pushes(current, spec_e, truth, first_e, use_identify, noise, log, warm, f"episode {index} ")
        rest = truth.let_go(release)
        observed.append(rest)
        aimed.append(np.array(spec_e.target))
        world = origin + rest
        episodes.append(Episode(index, origin, np.array(spec_e.target), _world(its, origin), origin + truth.pose,
                                world, _error(world, spec), 1 if truth.model.pad is None else 0,
                                time.perf_counter() - t0))
    return current, episodes, truth


def closed_loop(model_sc: Scenario, truth_sc: Scenario, spec: PlanSpec, use_identify: bool = False,
                noise: NoiseModel | None = None, log=None, warm: bool = True) -> dict:
    """Run the closed loop and the open-loop baseline; returns the ``closed_loop.json`` content
    and keeps the truth runs for the recording under ``"_truth"`` (removed before writing).

    After each push the re-plan aims at ``target - shift`` (:func:`modifier`): for a loaded
    target ``bias``, the truth's pose less the pose the plan expected after that push; for a
    rest target that bias and the model's loaded discrepancy weighed by the plan's
    spring-back.  A rest target is scored on the truth's
    rest pose after the release (the truth scenario's ``[release]``, else the model's); while
    that is outside the tolerance, the gripper grasps the block again where it rests and
    pushes the correction, ``spec.episodes`` grasp-push-release cycles at most (:mod:`.episodes`).
    ``warm``: re-plan in one :class:`~pushplan.planning.planner.PlanSession` on the planning
    mesh (without identification); False re-plans cold, each from the press on both meshes."""
    t_start = time.perf_counter()
    noise = noise or NoiseModel()
    press = press_commands(model_sc)
    release = truth_sc.release or model_sc.release
    first = plan(model_sc, spec, baseline=False)
    open_truth = _new_truth(truth_sc, press)
    open_truth.execute(planar_commands(first.commands))
    open_final = _final(open_truth, spec, release)
    truth = first_truth = _new_truth(truth_sc, press)
    current, iterations = _pushes(model_sc, spec, truth, first, use_identify, noise, log, warm)
    episodes = []
    if spec.target_state == "rest":
        current, episodes, truth = _episodes(current, spec, truth, first, iterations, release, press,
                                             (use_identify, noise, log, warm), t_start)
        iterations = [it for e in episodes for it in e.iterations]
        final_pose = episodes[-1].rest
    else:
        final_pose = truth.pose
    final = (_identified(identify(current, observations_from_steps(truth.steps), noise, LOOP_FIT, model_error=False))
             if use_identify else None)
    return {
        "scenario": model_sc.name, "truth": {"name": truth_sc.name, **_friction(truth_sc)},
        "model": _friction(model_sc), "plan": spec.to_dict(), "identify": use_identify,
        "scored_on": "rest pose after the truth's release" if spec.target_state == "rest" else "loaded pose",
        "open_loop": {"commands": [command_to_dict(c) for c in planar_commands(first.commands)],
                      "final_pose": _pose_json(open_final), "final_error": _error(open_final, spec)},
        "closed_loop": {"commands": [command_to_dict(it.command) for it in iterations],
                        "final_pose": _pose_json(final_pose), "final_error": _error(final_pose, spec),
                        "episodes": len(episodes) or None},
        "final_estimates": final,
        "iterations": [it.to_dict() for it in iterations],
        "episodes": [e.to_dict() for e in episodes],
        "wall_time_s": time.perf_counter() - t_start,
        "_truth": (first_truth, open_truth, [it.planned for it in episodes[0].iterations] if episodes
                   else [it.planned for it in iterations]),
    }


_pose_json = pose_json
