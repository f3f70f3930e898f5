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

from fe_contact import Model, State, StepReport

from ..config.commands import planar_commands
from ..config.plan import PlanSpec, press_commands
from ..config.scenario import Scenario
from ..errors import InputError, SolverFailure
from ..planning import plan
from ..planning.planner import PlanSession
from ..planning.replan import remaining_spec, replan
from ..planning.target import pose_error, within_tolerance
from ..run import StepSummary, drive
from ..run.observations import observations_from_steps
from .episodes import (Episode, episode_spec, gain_stop, progress_stop, reach_stop, regrasp, relative_summary,
                       response_gain, secant_gain)
from .fit import Identification, identify
from .loop_result import ClosedLoopResult, Iteration, RobustReplan, TruthRuns, error_json, friction_of
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


@dataclass(frozen=True)
class LoopOptions:
    """How the loop re-plans: ``identify`` re-identifies after each push (with ``noise``),
    ``robust`` (with ``identify``) re-plans robustly over the re-identified distribution,
    ``warm`` re-plans without identification in one session; ``log`` gets progress lines."""

    identify: bool = False
    noise: NoiseModel = field(default_factory=NoiseModel)
    log: object = None
    warm: bool = True
    robust: bool = False

    def say(self, text: str) -> None:
        if self.log is not None:
            self.log(text)


def _robust(model_sc: Scenario, est: Identification, spec: PlanSpec, replan_spec: PlanSpec, nominal, start,
            opts: LoopOptions):
    """The re-plan ``nominal`` refined robustly over ``est``'s distribution (undetermined
    parameters held at the estimate), scored against the loop's own tolerances (not the
    re-plan's :data:`REPLAN_TOLERANCE`), without a Monte Carlo check; returns the result
    and its :class:`RobustReplan` (None when no parameter is determined: the nominal stands)."""
    from ..planning.robust import plan_robust

    distribution, held = loop_distribution(est)
    if distribution is None:
        return nominal, None
    robust_spec = dataclasses.replace(remaining_spec(replan_spec, start), tolerance=spec.tolerance,
                                      yaw_tolerance=spec.yaw_tolerance,
                                      robust=dataclasses.replace(spec.robust, monte_carlo=0))
    r = plan_robust(model_sc, distribution, robust_spec, nominal, after=start.executed)
    ev = r.evaluations[r.best]
    opts.say(f"  robust re-plan: predicted probability {ev.probability:.4f} (nominal "
             f"{r.evaluations[0].probability:.4f}, level {spec.robust.level:g})")
    return r.result, RobustReplan(spec.robust.level, r.reached, ev.probability, r.evaluations[0].probability,
                                  distribution.names, held, len(r.evaluations), r.rollouts["sigma_point_rollouts"],
                                  sum(r.wall_time.values()))


def loop_distribution(est: Identification):
    """``(Distribution, held)``: the Gaussian of ``est``'s identifiable parameters (covariance
    ``corr * sigma sigma^T``), the others (undetermined: no finite variance) held at the
    estimate and named in ``held``; ``(None, held)`` when none is identifiable."""
    from ..planning.distribution import Distribution

    keep = [j for j, (s, ok) in enumerate(zip(est.sigma, est.identifiable, strict=True)) if ok and math.isfinite(s)]
    held = tuple(k for j, k in enumerate(est.names) if j not in keep)
    if not keep:
        return None, held
    sd = np.asarray(est.sigma, float)[keep]
    corr = np.nan_to_num(np.asarray(est.correlation, float)[np.ix_(keep, keep)])
    return Distribution(tuple(est.names[j] for j in keep), np.asarray(est.estimate, float)[keep],
                        corr * np.outer(sd, sd)), held


def _replan(model_sc, spec, truth, k, opts: LoopOptions, shift, session):
    """The re-plan before push ``k + 1`` (``k >= 1``): the model (re-identified with
    ``opts.identify``), the re-plan, the identification and the robust re-plan's record."""
    obs = observations_from_steps(truth.steps)
    est = robust = None
    if opts.identify:
        est = identify(model_sc, obs, opts.noise, LOOP_FIT, model_error=False)
        model_sc = est.scenario(model_sc)
        opts.say(f"step {k + 1}: identified " + ", ".join(f"{n} = {v:.5g}"
                                                        for n, v in zip(est.names, est.estimate, strict=True)))
    # the loop never reads the naive rollout: no baseline
    # warm in the session; cold with identification (another model each push)
    replan_spec = shifted_spec(spec, shift)
    result, start = replan(model_sc, replan_spec, obs, baseline=False, session=session)
    if opts.robust and est is not None:
        result, robust = _robust(model_sc, est, spec, replan_spec, result, start, opts)
    return model_sc, result, est, robust


def _step(model_sc, spec, truth, k, first, opts: LoopOptions, bias, shift, session):
    """Plan (or re-plan) with the current model and execute the next push on the truth
    (re-plans in the warm ``session`` unless identification changes the model)."""
    est = robust = None
    if k == 0:
        result = first
    else:
        model_sc, result, est, robust = _replan(model_sc, spec, truth, k, opts, shift, session)
    command = planar_commands(result.commands[:1])[0]
    planned = result.verified.lower + (truth.pose if k > 0 else 0.0)  # a re-plan's poses are relative
    planned[1:] += bias  # what the plan expects of the truth
    truth.execute([command])
    return model_sc, result, command, (est, robust), planned


def _final(truth: Truth, spec: PlanSpec, release) -> np.ndarray:
    """The pose scored against the target: the truth's rest pose after its release for a
    rest target, else its loaded pose."""
    return truth.rest_pose(release) if spec.target_state == "rest" else truth.pose


def _pushes(model_sc, spec, truth, first, opts: LoopOptions, label=""):
    """Execute ``first``'s pushes one at a time on ``truth``, re-planning after each
    (:func:`modifier`); returns the model planned with last and the iterations."""
    # the warm planner of the re-plans, on the planning mesh (the bias takes up its error too)
    session = PlanSession(model_sc, spec, verify=False) if opts.warm and not opts.identify else None
    if session is not None:
        session.follow(first)
    iterations, current, bias, drift = [], model_sc, np.zeros(3), np.zeros(3)
    springback = first.springback.fractions  # of the latest plan's calibration (re-identified models' too)
    for k in range(spec.steps):
        t0 = time.perf_counter()
        try:
            current, result, command, (est, robust), planned = _step(
                current, spec, truth, k, first, opts, bias, modifier(spec, bias, drift, springback), session)
        except InputError as e:
            raise LoopError(f"closed loop {label}step {k + 1}: {e}") from e
        bias = truth.pose - planned[1] + bias  # planned[1] holds the old bias
        # the model's loaded discrepancy from the truth; an identified model is fitted to the
        # observed poses, so its own is taken as none
        drift = np.zeros(3) if opts.identify else drift + bias
        if session is not None and spec.target_state == "rest" and k + 1 < spec.steps:
            # against the model the warm re-plans start from (the planning mesh), not the
            # verification mesh's pose the first plan expected: a bonded lift's rest is the
            # commanded pose, and their difference is what the re-plan would put in it
            drift = truth.pose - _model_pose(session, [it.command for it in iterations] + [command])
        springback = result.springback.fractions
        iterations.append(Iteration(k + 1, command, truth.pose, friction_of(current), result.status,
                                    result.message, sum(result.rollouts.values()), est, time.perf_counter() - t0,
                                    planned, robust))
        opts.say(f"{label}step {k + 1}: observed ({truth.pose[0] * 1e3:.5f}, {truth.pose[1] * 1e3:.5f}) mm, "
                 f"error {pose_error(truth.pose, spec)[0] * 1e6:.3f} um")
    return current, iterations


def _model_pose(session: PlanSession, executed) -> np.ndarray:
    """The lower-face pose ``(x, y, yaw)`` (m, rad) of the warm ``session``'s planning-mesh
    model after the pushes ``executed`` (fe_contact Commands after the press): the state its
    next re-plan starts from (executed there once, as the re-plan would)."""
    session.continue_from(executed)
    rep = session.coarse.pressed().reports[-1]
    return np.array([rep.lower_centroid[0], rep.lower_centroid[1], rep.lower_yaw])


def _world(iterations, origin) -> tuple:
    """``iterations`` with their poses moved from an episode's frame to the world's."""
    return tuple(dataclasses.replace(it, observed=it.observed + origin, planned=it.planned + origin)
                 for it in iterations)


def _episodes(current, spec, truth, iterations, release, press, opts: LoopOptions, t_start):
    """The first episode's release and, while its rest pose is outside the tolerance,
    further episodes (:mod:`.episodes`), ``spec.episodes`` in all at most, each aiming at
    what is left over the truth's response gain of the one before
    (:func:`~.episodes.response_gain`; of the last one in reach of its steps).  The loop
    stops (a failure, reported) when an episode aimed over a measured gain removes less
    than :data:`~.episodes.MIN_PROGRESS` of the error it started from
    (:func:`~.episodes.progress_stop`), or before an episode that the measured gain, or the
    last episode's reach, says cannot (:func:`~.episodes.gain_stop`, :func:`~.episodes.reach_stop`).  Returns the model planned with last, the
    episodes, the last episode's truth and why the loop stopped early (a
    :class:`~.episodes.Stop`, or None)."""
    truth.let_go(release)
    episodes = [Episode(1, np.zeros(3), np.array(spec.target), tuple(iterations), truth.pose, truth.rest,
                        error_json(truth.rest, spec), 0, time.perf_counter() - t_start)]
    stop, gain, measured = None, np.ones(3), False  # measured: the next episode aims over a measured gain
    while len(episodes) < spec.episodes and not within_tolerance(episodes[-1].rest, spec):
        t0, index, last = time.perf_counter(), len(episodes) + 1, episodes[-1]
        origin = last.rest
        moved = last.rest - last.origin
        if not any(it.plan_status == "infeasible" for it in last.iterations):
            gain, measured = response_gain(moved, last.aimed), True
            stop = gain_stop(secant_gain(moved, last.aimed), last.rest, last.index, spec)
        else:  # an episode that aimed beyond reach went as far as the steps allow: says nothing of the gain
            stop = reach_stop(moved, last.rest, last.index, spec)
        if stop is not None:
            break
        spec_e = episode_spec(spec, origin, gain)
        opts.say(f"episode {index}: rest {pose_error(origin, spec)[0] * 1e6:.3f} um off, re-grasp")
        truth = truth.regrasped(press)
        first_e = plan(current, spec_e, baseline=False)
        current, its = _pushes(current, spec_e, truth, first_e, opts, f"episode {index} ")
        rest = truth.let_go(release)
        world = origin + rest
        episodes.append(Episode(index, origin, np.array(spec_e.target), _world(its, origin), origin + truth.pose,
                                world, error_json(world, spec), 1 if truth.model.pad is None else 0,
                                time.perf_counter() - t0))
        stop = progress_stop(origin, world, index, spec) if measured else None
        if stop is not None:
            break
    if stop is not None:
        opts.say(stop.message)
    return current, episodes, truth, stop


def closed_loop(model_sc: Scenario, truth_sc: Scenario, spec: PlanSpec, use_identify: bool = False,
                noise: NoiseModel | None = None, log=None, warm: bool = True,
                robust: bool = False) -> ClosedLoopResult:
    """Run the closed loop and the open-loop baseline (its ``to_dict()`` is the
    ``closed_loop.json`` content; ``runs`` the truth runs for the recording).

    After each push the re-plan aims at ``target - shift`` (:func:`modifier`): for a loaded
    target ``bias``, the truth's pose less the pose the plan expected after that push; for a
    rest target that bias and the model's loaded discrepancy weighed by the plan's
    spring-back.  A rest target is scored on the truth's
    rest pose after the release (the truth scenario's ``[release]``, else the model's); while
    that is outside the tolerance, the gripper grasps the block again where it rests and
    pushes the correction, ``spec.episodes`` grasp-push-release cycles at most (:mod:`.episodes`).
    ``warm``: re-plan in one :class:`~pushplan.planning.planner.PlanSession` on the planning
    mesh (without identification); False re-plans cold, each from the press on both meshes.
    ``robust`` (with ``use_identify``): each re-plan is refined to ``spec.robust.level`` over
    the re-identified estimate and covariance (:func:`_robust`)."""
    t_start = time.perf_counter()
    opts = LoopOptions(use_identify, noise or NoiseModel(), log, warm, robust and use_identify)
    press = press_commands(model_sc)
    release = truth_sc.release or model_sc.release
    first = plan(model_sc, spec, baseline=False)
    open_truth = _new_truth(truth_sc, press)
    open_truth.execute(planar_commands(first.commands))
    open_final = _final(open_truth, spec, release)
    truth = first_truth = _new_truth(truth_sc, press)
    current, iterations = _pushes(model_sc, spec, truth, first, opts)
    episodes, stopped = [], None
    if spec.target_state == "rest":
        current, episodes, truth, stopped = _episodes(current, spec, truth, iterations, release, press, opts,
                                                      t_start)
        iterations = [it for e in episodes for it in e.iterations]
        final_pose = episodes[-1].rest
    else:
        final_pose = truth.pose
    final = (identify(current, observations_from_steps(truth.steps), opts.noise, LOOP_FIT, model_error=False)
             if use_identify else None)
    planned = tuple(it.planned for it in (episodes[0].iterations if episodes else iterations))
    return ClosedLoopResult(
        scenario=model_sc, truth=truth_sc, spec=spec, identify=use_identify, robust=opts.robust,
        open_commands=tuple(planar_commands(first.commands)), open_final=open_final, final_pose=final_pose,
        iterations=tuple(iterations), episodes=tuple(episodes), final_estimates=final, stopped=stopped,
        wall_time=time.perf_counter() - t_start, runs=TruthRuns(first_truth, open_truth, planned))
