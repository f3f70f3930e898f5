"""The planning NLP on the reduced model (:mod:`.reduced_model`), transcribed with
CasADi ``Opti`` and solved by ipopt.

Commands ``u_k = (dx, dy[, dtheta])`` within the step bounds minimise the
final-pose error plus a small effort cost.  The return mapping of each step is
transcribed with its complementarity (slip only on the limit surface), relaxed to
``sigma (1 - rho) <= COMPLEMENTARITY_EPS``.  The problem is built once for a horizon of
K steps and re-solved with new parameter values: the ``modifier`` (the FE-minus-model
mismatch of the correction loop) and, for a re-plan of the last ``m <= K`` steps
(:meth:`ReducedPlanner.retarget`), the target, the tolerances, the start lag and which
steps are active (the last ``K - m`` are held still: zero command).

A warm solve (from an earlier solution) first solves the smooth NLP of the warm start's
branch of the complementarity (each step sliding, ``rho = 1``, or sticking, ``sigma = 0``)
and keeps its answer only where it is a solution of the full problem that no step wants to
leave; otherwise it solves the full MPCC from the same start
(:meth:`ReducedPlanner._solve_active_set`): the MPCC's interior point crawls (89 ipopt
iterations on ``plan_rubber``'s first re-plan, 30 for the smooth NLP).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..config.plan import PlanSpec
from .reduced_model import PushParameters, push_law, simulate_reduced
from .springback import Springback
from .target import naive_commands

COMPLEMENTARITY_EPS = 1e-8
"""Relaxation of ``sigma_k (1 - rho_k) = 0`` (slip, in units of max_step, times the
distance of the force from the limit surface, relative)."""
ACTIVE_SET_MAX_ITER = 60
"""ipopt's iteration cap on the active-set NLP (:meth:`ReducedPlanner._solve_active_set`):
a warm re-plan whose branch holds takes 6-25 on ``plan_rubber``'s closed loop; one that
needs more (a branch far from the answer can crawl for hundreds) goes to the full MPCC,
so a warm solve costs at most this many iterations more than the full one alone."""
ACTIVE_SET_OPTIONS = {"ipopt.max_iter": ACTIVE_SET_MAX_ITER, "ipopt.tol": 1e-12}
"""Added to the warm options for the active-set NLP.  Its ``tol`` is 1e-12: at 1e-10 it
stops in the nearly flat valley of how the effort is shared between the steps 4.7e-8 m of
commands (2.5e-7 m of planned poses) from where it ends at 1e-12, on ``plan_rubber``'s
first re-plan, for 28 instead of 30 iterations; at 1e-12 its answers are within 6.2e-9 m
of commands of the full MPCC's (``benchmarks/replan_phases.py --compare nlp``)."""
BIACTIVE = 1e-6
"""A step of the active-set NLP is on both bounds of the complementarity when its other
variable is within this of its bound (sigma in units of max_step, 1 - rho relative)."""
MULTIPLIER_TOL = 1e-6
"""How far a bound multiplier of the active-set NLP may have the wrong sign (objective
units, the objective being O(1) at the target's tolerance) and still count as zero
(:meth:`ReducedPlanner._solve_active_set`); inactive bounds' multipliers are ~4e-8 at
ipopt's ``tol`` 1e-10, a step that wants to switch has ~1e4."""

SOLVER_OPTIONS = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": 3000,
                  "ipopt.tol": 1e-10, "ipopt.mu_strategy": "adaptive", "ipopt.bound_push": 1e-8,
                  "ipopt.bound_frac": 1e-8}
"""ipopt's options.  The starting point is complementary, with rho = 1 on its bound where
sigma > 0: ipopt's default bound push (1e-2) would move it off the complementarity set."""
WARM_START_OPTIONS = {"expand": True, "ipopt.warm_start_init_point": "yes"}
"""Added for a solve from an earlier solution (a correction's re-solve, a session's re-plan),
which has its own ipopt instance: ipopt starts from the given point with its multipliers,
here zero, raised to ``warm_start_mult_bound_push`` (1e-3), instead of its least-squares
estimate; the functions are expanded to CasADi's scalar graph (the same functions, 2-3 x
cheaper per iteration).  On ``plan_rubber``'s closed loop (``benchmarks/serve_latency.py``)
the re-plans took 36 / 153 / 23 / 15 / 16 iterations without these options and 48 / 21 /
11 / 12 / 12 with them.  On the same requests the answers agree to 1.3e-9 m (commands) and
5.9e-9 m (poses), except where the start without them crawls along the complementarity set
(the 153 iterations): there it stopped, within ipopt's ``tol``, 2.3e-7 m of commands from
the point these options reach, with an objective 1e-7 (relative) higher and the same
reduced-model final pose (4e-16 m), along the nearly flat direction of how the effort is
shared between the steps; three other ipopt set-ups (no scaling, the probing or LOQO mu
oracle) reach the warm start's point within 1.1e-9 m.  A cold solve (from
:meth:`ReducedPlanner.initial_guess`) keeps the options above alone."""


@dataclass(frozen=True)
class NlpSolution:
    """One solve of the planning NLP.

    ``commands`` (K, 3) ``(dx, dy, dtheta)``; ``lower`` / ``upper`` (K + 1, 3) reduced-model
    poses (without the modifier); ``variables`` the raw iterate (warm start).  ``path``:
    ``"mpcc"`` (the full problem), ``"active_set"`` (the smooth NLP of the warm start's
    branch, :meth:`ReducedPlanner._solve_active_set`) or ``"mpcc_after_active_set_failed"`` /
    ``"..._switch"`` (the full problem after it; ``iterations`` and ``wall_time`` count both
    runs); ``bound_multipliers`` (2, K) the active-set NLP's of ``rho <= 1`` and ``sigma >= 0``.
    """

    commands: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    objective: float
    iterations: int
    success: bool
    return_status: str
    wall_time: float
    variables: dict = field(repr=False)
    bound_multipliers: np.ndarray | None = field(default=None, repr=False)
    path: str = "mpcc"


class ReducedPlanner:
    """The planning NLP on the reduced model, built once for ``spec.steps`` = K steps;
    re-solved with new parameter values (transcribed by CasADi ``Opti``, solved by ipopt
    through the nlpsol of that transcription, never rebuilt).

    Per step k: the unit direction ``a_k`` of the generalised drive force on the
    limit surface (orthotropy frame, scaled by the friction limits), its level
    ``rho_k`` in [0, 1] (1 = on the surface) and the slip length ``sigma_k >= 0`` (in
    units of ``max_step``).  Poses follow explicitly through the one
    :func:`~.reduced_model.push_law` (the lower face slips along the surface normal,
    the upper face leads it by the elastic lag), the law the return mapping
    :func:`~.reduced_model.simulate_reduced` evaluates numerically.  The objective is

        J = |p_m + modifier - x*|^2 / tol^2 [+ (yaw_m + ... - yaw*)^2 / yaw_tol^2]
            + w sum_k |u_k / bound|^2 / m

    over the m active steps (:meth:`retarget`; m = K unless re-planning); an inactive
    step ``k >= m`` keeps the poses of the last active one (zero command) and its
    variables are pinned by a term ``|a - e_1|^2 + rho^2 + sigma^2`` of their own (an
    active step's problem is the one of a horizon of m).

    A warm :meth:`solve` tries the warm start's active set first (:attr:`active_set`,
    :meth:`_solve_active_set`); ``NlpSolution.path`` says which problem answered.

    ``initial_lag`` (3,) ``upper - lower`` at the start (m, m, rad): zero from the pressed
    block at rest; a re-plan starts from the loaded state the executed pushes left, whose
    drive force is already on (or near) the limit surface.
    """

    active_set: bool = True
    """A warm solve tries the warm start's active set first (:meth:`_solve_active_set`)."""

    def __init__(self, params: PushParameters, spec: PlanSpec, springback: Springback | None = None,
                 initial_lag=(0.0, 0.0, 0.0)):
        if spec.yaw_targeted and not params.rotation:
            raise ValueError("a yaw target needs a reduced model with torsional parameters")
        self.params, self.horizon = params, spec.steps
        self.law = push_law(params)  # for the numerical return mapping (simulate_reduced)
        # the pose the target is for: loaded, or at rest after the release (spring-back of the lag)
        self.springback = springback if spec.target_state == "rest" else None
        self._cold = _Program(self.law, spec, self.springback, SOLVER_OPTIONS)
        self._warm = _Program(self.law, spec, self.springback, SOLVER_OPTIONS | WARM_START_OPTIONS)  # its own ipopt
        self._smooth = _Program(self.law, spec, self.springback, SOLVER_OPTIONS | WARM_START_OPTIONS
                                | ACTIVE_SET_OPTIONS, active_set=True)
        self._base = spec
        self.retarget(spec, initial_lag)

    def retarget(self, spec: PlanSpec, initial_lag=(0.0, 0.0, 0.0)) -> None:
        """Plan ``spec`` (its target, tolerances and ``steps`` = m <= K active steps) from
        ``initial_lag`` (3,) m, m, rad at the next solves.

        Raises
        ------
        ValueError
            ``spec`` differs from the built one in anything but those (bounds, effort
            weight, target state, yaw targeting) or has more steps than the horizon.
        """
        fixed = ("yaw_targeted", "max_step", "max_dtheta", "effort_weight", "target_state")
        changed = [k for k in fixed if getattr(spec, k) != getattr(self._base, k)]
        if changed or not 1 <= spec.steps <= self.horizon:
            raise ValueError(f"retarget: {spec.steps} steps on a horizon of {self.horizon}, changed {changed}")
        self.spec = spec
        self.initial_lag = np.asarray(initial_lag, float) * np.array([1.0, 1.0, float(spec.yaw_targeted)])

    def predicted_final(self, solution: NlpSolution) -> np.ndarray:
        """The reduced model's final pose (3,) in the target's state (without the modifier)."""
        if self.springback is None:
            return solution.lower[-1]
        return self.springback.rest(solution.lower[-1], solution.upper[-1])

    def initial_guess(self) -> dict:
        """The variables of the naive commands (clipped to the step bounds), from the
        reduced model's return mapping: a feasible, complementary starting point
        (inactive steps at their pinned values)."""
        p, spec = self.params, self.spec
        cmds = naive_commands(spec)
        cmds[:, :2] *= min(1.0, spec.max_step / max(float(np.hypot(*cmds[0, :2])), 1e-300))
        cmds[:, 2] = np.clip(cmds[:, 2], -spec.max_dtheta, spec.max_dtheta)
        traj = simulate_reduced(p, cmds, self.law)
        m = np.array([p.mu_x, p.mu_y])
        f_local = traj.force[1:, :2] @ p.frame  # rows R^T f
        scaled = f_local / (p.normal_force * m)
        if spec.yaw_targeted:
            scaled = np.column_stack([scaled, traj.force[1:, 2] / p.max_torque])
        rho = np.linalg.norm(scaled, axis=1)
        A = np.where(rho[:, None] > 0, scaled / np.where(rho > 0, rho, 1.0)[:, None], 0.0)
        A[rho == 0, 0] = 1.0
        slip = np.diff(traj.lower[:, :2], axis=0) @ p.frame
        per_unit = spec.max_step * math.sqrt(p.mu_x * p.mu_y) * np.linalg.norm(A[:, :2] / m, axis=1)
        sigma = np.where(traj.sliding[1:], np.linalg.norm(slip, axis=1) / np.maximum(per_unit, 1e-300), 0.0)
        return _padded({"A": A.T, "rho": np.minimum(rho, 1.0)[None, :], "sigma": sigma[None, :]}, self.horizon)

    def solve(self, modifier=(0.0, 0.0, 0.0), warm: NlpSolution | None = None) -> NlpSolution:
        """Solve for the commands of the active steps; ``modifier`` (3,) is added to the
        predicted final pose; ``warm``: a solve to start from (its variables, padded or
        cut to the horizon; ipopt warm-started, :data:`WARM_START_OPTIONS`), else
        :meth:`initial_guess` (a cold start).

        A failed ipopt run returns its last iterate with ``success = False``.
        """
        spec, m = self.spec, self.spec.steps
        values = {"target": list(spec.target), "modifier": [float(v) for v in modifier],
                  "lag0": [float(v) for v in self.initial_lag], "active": [1.0] * m + [0.0] * (self.horizon - m),
                  "weights": [spec.tolerance**-2, spec.yaw_tolerance**-2, spec.effort_weight / m]}
        if warm is None:
            return self._cold.solve(values, self.initial_guess(), m)
        guess = _padded(warm.variables, self.horizon, m)
        if not self.active_set:
            return self._warm.solve(values, guess, m)
        smooth = self._solve_active_set(values, guess, m)
        if smooth.path == "active_set":
            return smooth
        full = self._warm.solve(values, guess, m)
        return dataclasses.replace(full, iterations=full.iterations + smooth.iterations,
                                   wall_time=full.wall_time + smooth.wall_time, path=smooth.path)

    def _solve_active_set(self, values: dict, guess: dict, m: int) -> NlpSolution:
        """The smooth NLP of the warm start's branch of the complementarity, per step: a
        step that slides (``sigma_k > 1 - rho_k`` in ``guess``) keeps ``rho_k = 1``,
        ``sigma_k >= 0``; one that sticks keeps ``sigma_k = 0``, ``0 <= rho_k <= 1``.

        Its answer (``path = "active_set"``) is kept when it is a solution of the MPCC
        ``0 <= sigma _|_ 1 - rho >= 0`` that no step wants to leave: ipopt converged on the
        smooth NLP (its KKT conditions hold, the complementarity by construction); no
        sticking step wants to slip (the multiplier of its ``sigma >= 0`` is ``<=
        MULTIPLIER_TOL``, CasADi's sign: positive = the upper bound holds, so the objective
        would raise sigma); and a sliding step that stopped (``sigma <= BIACTIVE``, on both
        bounds) does not want off the limit surface (its ``rho <= 1``'s multiplier is ``>=
        -MULTIPLIER_TOL``).  A sliding step with ``sigma > BIACTIVE`` may have a negative
        ``rho <= 1`` multiplier: lowering rho there means stopping first, not a local move,
        and the full solve's relaxation (:data:`COMPLEMENTARITY_EPS`) only lets its rho sit at
        ``1 - eps / sigma``, so the two answers differ by that relaxation.  The test on the
        sticking steps is stricter than strong stationarity (which asks signs only of steps
        on both bounds): a stuck step whose objective wants slip sends the re-plan to the
        full MPCC, whose local answer may slide there.  Otherwise ``path`` names the reason
        (``"mpcc_after_active_set_failed"`` / ``"mpcc_after_active_set_switch"``) and
        :meth:`solve` solves the full MPCC from the same guess: at most two ipopt runs."""
        slides = (np.asarray(guess["sigma"], float) > 1.0 - np.asarray(guess["rho"], float)).ravel()
        fixed = dict(guess, rho=np.where(slides, 1.0, guess["rho"]), sigma=np.where(slides, guess["sigma"], 0.0))
        bounds = {"rho_lo": np.where(slides, 1.0, 0.0).tolist(), "sigma_hi": np.where(slides, 1e20, 0.0).tolist()}  # >= 1e19: none
        sol = self._smooth.solve(values | bounds, fixed, m)
        if not sol.success:
            return dataclasses.replace(sol, path="mpcc_after_active_set_failed")
        lam_rho, lam_sigma = sol.bound_multipliers
        sigma = sol.variables["sigma"].ravel()
        lowers_rho = slides & (sigma <= BIACTIVE) & (lam_rho < -MULTIPLIER_TOL)
        switch = lowers_rho | (~slides & (lam_sigma > MULTIPLIER_TOL))
        return dataclasses.replace(sol, path="mpcc_after_active_set_switch" if switch.any() else "active_set")


class _Program:
    """The planning NLP of :class:`ReducedPlanner` (``law``: its :func:`push_law`)
    transcribed in its own ``Opti`` with its own ipopt ``options`` (:data:`SOLVER_OPTIONS`,
    :data:`WARM_START_OPTIONS`)."""

    def __init__(self, law, spec: PlanSpec, springback: Springback | None, options: dict,
                 active_set: bool = False):
        import casadi as ca

        K, d = spec.steps, (3 if spec.yaw_targeted else 2)
        opti = ca.Opti()
        A, rho, sigma = opti.variable(d, K), opti.variable(1, K), opti.variable(1, K)
        par = {name: opti.parameter(n) for name, n in
               (("target", 3), ("modifier", 3), ("lag0", 3), ("active", K), ("weights", 3))}
        lower, upper, cmds, effort, pinned = _chain(ca, opti, law, (A, rho, sigma), par, spec)
        self.fixed = ()
        if active_set:  # the complementarity's branch per step as bounds: rho_lo <= rho <= 1, 0 <= sigma <= sigma_hi
            par["rho_lo"], par["sigma_hi"] = opti.parameter(1, K), opti.parameter(1, K)
            self.fixed = (opti.bounded(par["rho_lo"], rho, 1), opti.bounded(0, sigma, par["sigma_hi"]))
            for c in self.fixed:
                opti.subject_to(c)
        else:
            opti.subject_to(opti.bounded(0, rho, 1))
            opti.subject_to(sigma >= 0)
            opti.subject_to(sigma * (1 - rho) <= COMPLEMENTARITY_EPS)
        final = lower[-1] + par["modifier"]
        if springback is not None:
            final = final + ca.DM(springback.fractions) * (upper[-1] - lower[-1])
        miss = final[:2] - par["target"][:2]
        w = par["weights"]  # 1 / tol^2, 1 / yaw_tol^2, effort_weight / m
        objective = ca.sumsqr(miss) * w[0] + effort * w[2]
        if spec.yaw_targeted:
            objective += (final[2] - par["target"][2]) ** 2 * w[1]
        opti.minimize(objective + pinned)
        opti.solver("ipopt", options)  # Opti's own solve is the reference (tests/test_replan_fast.py)
        self.opti, self.par, self.variables, self.K, self.d = opti, par, {"A": A, "rho": rho, "sigma": sigma}, K, d
        # every output in one vector: one evaluation per solve (column-major blocks)
        self.outputs = ca.veccat(ca.horzcat(*cmds), ca.horzcat(*lower), ca.horzcat(*upper), objective, A, rho, sigma,
                                 *(opti.dual(c) for c in self.fixed))
        # Opti transcribes; a solve calls ipopt through an nlpsol of Opti's own problem (x, p,
        # f, g, the bounds lbg / ubg) and two functions, all built at the first solve (as Opti
        # builds its own), without Opti's per-solve work (setting values, the bounds and the
        # outputs through helper functions built at every call): the same ipopt run
        self._options, self._compiled = options | {"error_on_fail": False}, None

    @property
    def solver(self):
        """The nlpsol of the transcription (built at the first use)."""
        return self._compile()[0]

    def _compile(self) -> tuple:
        """``(nlpsol, bounds(p) -> (lbg, ubg), outputs(x, p, lam_g), p order, x order, lam_g0)``,
        built once."""
        if self._compiled is None:
            import casadi as ca

            opti = self.opti
            self._compiled = (
                ca.nlpsol("nlp", "ipopt", {"x": opti.x, "p": opti.p, "f": opti.f, "g": opti.g}, self._options),
                ca.Function("bounds", [opti.p], [opti.lbg, opti.ubg]),
                ca.Function("outputs", [opti.x, opti.p, opti.lam_g], [self.outputs]),
                _layout(ca, list(self.par.values()), opti.p), _layout(ca, list(self.variables.values()), opti.x),
                np.zeros(opti.ng),  # as Opti: ipopt's multipliers start at zero
            )
        return self._compiled

    def solve(self, values: dict, guess: dict, m: int) -> NlpSolution:
        """Solve with parameter ``values`` (every parameter by name) from ``guess`` (variables
        by name), ``m`` active steps."""
        solver, bounds, outputs, p_order, x_order, lam_g0 = self._compile()
        p = _packed([values[name] for name in self.par], p_order)
        lbg, ubg = bounds(p)
        x0 = _packed([guess[name] for name in self.variables], x_order)
        t0 = time.perf_counter()
        failure = None
        with interrupts_kept():
            try:  # ipopt's failure is its last iterate (error_on_fail False; a Ctrl-C is raised after)
                res = solver(x0=x0, p=p, lbg=lbg, ubg=ubg, lam_g0=lam_g0)
            except RuntimeError as e:  # a Ctrl-C inside ipopt, raised after the block; else CasADi's error
                failure = e
        if failure is not None:
            raise failure
        wall = time.perf_counter() - t0
        stats = solver.stats()
        out, K, d = np.asarray(outputs(res["x"], p, res["lam_g"]), float).ravel(), self.K, self.d
        parts = np.split(out, np.cumsum([3 * K, 3 * (K + 1), 3 * (K + 1), 1, d * K, K, K]))
        return NlpSolution(
            commands=parts[0].reshape(K, 3)[:m].copy(),
            lower=parts[1].reshape(K + 1, 3)[:m + 1].copy(),
            upper=parts[2].reshape(K + 1, 3)[:m + 1].copy(),
            objective=float(parts[3][0]),
            iterations=int(stats.get("iter_count", -1)),
            success=bool(stats.get("success", False)),
            return_status=str(stats.get("return_status", "")),
            wall_time=wall,
            variables={"A": parts[4].reshape(K, d).T.copy(), "rho": parts[5][None, :].copy(),
                       "sigma": parts[6][None, :].copy()},
            bound_multipliers=_net_multipliers(parts[7], K) if self.fixed else None,
        )


def _layout(ca, symbols: list, vector) -> np.ndarray:
    """Where the entries of ``vector`` (Opti's ``x`` or ``p``, its symbols stacked) come
    from: indices into the column-major entries of ``symbols`` laid end to end."""
    sizes = [s.numel() for s in symbols]
    starts = np.cumsum([0, *sizes])
    numbered = [ca.DM(np.arange(a, a + n, dtype=float).reshape(s.shape, order="F"))
                for a, n, s in zip(starts[:-1], sizes, symbols, strict=True)]
    order = np.asarray(ca.Function("layout", symbols, [vector])(*numbered), float).ravel()
    if sorted(order) != list(range(int(starts[-1]))):
        raise AssertionError("Opti's vector is not its symbols stacked")
    return order.astype(int)


def _packed(arrays: list, order: np.ndarray) -> np.ndarray:
    """The arrays' column-major entries laid end to end, in Opti's ``order`` (:func:`_layout`)."""
    return np.concatenate([np.ravel(np.asarray(a, float), order="F") for a in arrays])[order]


def _net_multipliers(duals: np.ndarray, K: int) -> np.ndarray:
    """(2, K) multipliers of the active-set NLP's ``rho_lo <= rho <= 1`` and ``0 <= sigma <=
    sigma_hi`` in CasADi's sign (positive: the upper bound holds the variable).  ``Opti``
    splits a two-sided bound with a parameter into its two sides, dual (1, 2K): the
    lower side's multipliers then the upper side's, each >= 0."""
    d = duals.reshape(2, -1)
    return d[:, K:] - d[:, :K] if d.shape[1] == 2 * K else d


def _chain(ca, opti, law, variables, par, spec: PlanSpec):
    """The poses of :class:`ReducedPlanner` step by step through ``law`` (its docstring),
    with the per-step constraints added to ``opti``: (lower poses, upper poses, commands,
    effort term, pinning term of the inactive steps)."""
    A, rho, sigma = variables
    K = spec.steps
    lower, upper, cmds = [ca.DM.zeros(3, 1)], [par["lag0"]], []
    effort = pinned = 0
    for k in range(K):
        a, on = A[:, k], par["active"][k]
        # without a yaw target the force has no torque and the slip no yaw
        p, u, _ = law(lower[-1], a if spec.yaw_targeted else ca.vertcat(a, 0), rho[k],
                      spec.max_step * sigma[k])
        # an inactive step (on = 0) keeps the poses: its variables only pin themselves
        p, u = on * p + (1 - on) * lower[-1], on * u + (1 - on) * upper[-1]
        pinned += (1 - on) * ((a[0] - 1) ** 2 + ca.sumsqr(a[1:]) + rho[k] ** 2 + sigma[k] ** 2)
        du = u - upper[-1]
        lower.append(p)
        upper.append(u)
        cmds.append(du)
        # constraints in units of the bounds: ipopt's feasibility tolerance is absolute
        opti.subject_to(ca.sumsqr(a) == 1)
        opti.subject_to(ca.sumsqr(du[:2] / spec.max_step) <= 1)
        effort += ca.sumsqr(du[:2] / spec.max_step)
        if spec.yaw_targeted:
            opti.subject_to(opti.bounded(-1, du[2] / spec.max_dtheta, 1))
            effort += (du[2] / spec.max_dtheta) ** 2
    return lower, upper, cmds, effort, pinned


@contextlib.contextmanager
def interrupts_kept():
    """Raise ``KeyboardInterrupt`` after the block when a Ctrl-C (SIGINT) came during it.

    CasADi runs Python's signal handler from inside ipopt and turns the
    ``KeyboardInterrupt`` into a failed solve (a ``RuntimeError``, or a last iterate):
    without this guard a Ctrl-C in the NLP went on to a complete "converged" plan, exit
    0.  Only in the main thread with Python's own handler installed (a SIGINT ignored
    stays ignored)."""
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield
        return
    hit: list[int] = []

    def handler(signum, frame):
        hit.append(signum)
        previous(signum, frame)

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if hit:
        raise KeyboardInterrupt


def _padded(variables: dict, horizon: int, active: int | None = None) -> dict:
    """NLP variables cut to their first ``active`` steps (default: all) and padded to
    ``horizon`` columns with an inactive step's pinned values (``a = e_1``, ``rho = sigma = 0``)."""
    out = {}
    for name, v in variables.items():
        v = np.asarray(v, float)[:, :active]
        tail = np.zeros((v.shape[0], horizon - v.shape[1]))
        if name == "A":
            tail[0] = 1.0
        out[name] = np.hstack([v, tail])[:, :horizon]
    return out


def model_consistency(params: PushParameters, solution: NlpSolution, law=None) -> float:
    """Largest difference (m or rad) between the NLP's lower-face poses and the return
    mapping of its commands (:func:`simulate_reduced`): both go through the one
    :func:`push_law`, so this measures the relaxation of the NLP's complementarity
    ``sigma (1 - rho) <= COMPLEMENTARITY_EPS`` (slip off the limit surface); ``law``:
    ``push_law(params)`` if already built."""
    cmds = solution.commands.copy()
    if not params.rotation:
        cmds[:, 2] = 0.0
    traj = simulate_reduced(params, cmds, law)
    return float(np.abs(traj.lower - solution.lower).max())

