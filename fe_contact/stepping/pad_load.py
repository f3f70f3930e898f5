"""A frictional pad unloaded by load control (issue 39): the pad's height is
one more unknown of the step, its load one more equation.

A release step prescribes the pad's total normal load ``P`` (N,
:class:`~fe_contact.stepping.command.PadLoad`); the pad's height ``h`` (m) is
solved with the displacements and the contact forces in the step's Newton
loop (:mod:`fe_contact.stepping.newton`), closed by

    g(h) = sum_{c in pad} r_n,c - P = 0.                                  (N)

The pad moves on the release's path: from the step's start pose ``t_0``,
``t(h) = t_0 + a (h - h_0)``, ``a = (a_x, a_y, 1)`` (the retreat per unit
rise), no turn.  Its contacts' kinematics (gap ``n . (x - p - t)`` and slip
``T (du - m)``, :meth:`~fe_contact.contact.bodies.ContactSet.kinematics`) are
affine in ``h``, so the condensed local problem of a Newton iteration
(``u = W r + q``, :mod:`fe_contact.stepping.newton`) is bordered by one column,

    u = W r + q + b (h - h_i),    b_c = -T_c a  (pad contacts; 0 on the floor),  m/m,

and one row, ``e^T r = P`` (``e`` picks the pad's normal forces): the bordered
system ``[[K, -b], [c^T, 0]]`` of load control condensed onto the contacts,
whose elimination needs the factor of ``K`` once (``W``) and the one more
column ``b``.  The row is solved with the contact law: ``g`` is a monotone
(decreasing), piecewise smooth function of ``h`` through the local solution
``r(h)``; its root is bracketed from the last slope ``-dg/dh`` and closed by
the Illinois variant of regula falsi (Dahlquist & Bjorck, *Numerical methods*,
sect. 6.2.3), to ``|g| <= LOAD_TOL`` of the load scale, in at most
:data:`MAX_LOAD_EVALUATIONS` local solves per Newton iteration.  Every such
solve is a local solve of the iteration (no global step, no factorisation);
the outer loop sees one iteration.  At ``P = 0`` every ``h`` above the pad's
opening is a root: the block's state does not depend on which.  Where the
load jumps across its target at one height (a frictional local problem whose
pad lets go at once: measured 0.35 W on a pad 3 x the floor's, anisotropic),
the step ends past the jump, at that height, with its load below the target;
the schedule's next load below it follows (:class:`~fe_contact.stepping.release.ReleaseSchedule`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .command import Command, PadLoad
from .held import pad_loading, pad_motion
from .law_check import checked
from .measure import measure
from .model import Model, State, Status
from .newton import equilibrium
from .predictor import commanded_pose, guessed_start

__all__ = ["LoadDrive", "LOAD_TOL", "MAX_LOAD_EVALUATIONS", "load_step", "pad_normal_load", "path_tolerance"]

LOAD_TOL = 1e-10
"""The pad's load equation is met to this fraction of the load scale (the loaded pad load, or the weight)."""
LOCAL_TOL = 1e-13
"""The local solves of a load equation meet this natural-map residual (or ``local_tol`` if tighter): a warm start
within a looser tolerance returns the start unchanged, and the pad's load is then a staircase of the height."""
NOISE_CAP = 1e-7
"""The local solves' own error of the pad's load is trusted up to this fraction of the load scale (their
tolerance is relative to ``max(|q|, |r|, |u|)``, which an open contact's gap can make large)."""
JUMP_WIDTH = 1e-10
"""A bracket of the load equation narrower than this fraction of the heights holds a jump of the load."""
MAX_FAILED_PROBES = 4
"""Points of one load equation's bracket, and of its regula falsi, that no local method solves, at most each
(:meth:`LoadDrive._bracket`, :meth:`LoadDrive._illinois`)."""
WARM_STALL = 20
"""A warm-started local solve of the load equation is given up after this many semismooth Newton steps that did not
halve its best residual (:func:`~fe_contact.contact.local_solver.solve_checked`): a warm start from another
height's stick / slip pattern can wander for its 100 steps where the start from zero forces converges."""
MAX_LOAD_EVALUATIONS = 60
"""Local solves of one Newton iteration's load equation at most (bracket and Illinois together)."""


class LoadDrive:
    """The pad's height (and a compliant gripper's plate pose) as unknowns of a
    step's Newton loop (module docstring).

    Parameters
    ----------
    model : Model
        With a frictional pad.
    state : State
        The step's start (its pad pose: the plate's ``(x, y, theta)`` and the height).
    command : PadLoad or Command
        The load ``P`` at the end of the step and the path's retreat; or, for a
        compliant gripper, a commanded pose (the height given, no load equation).
    scale : float
        Load scale, N (the loaded pad load, or the weight): the tolerance's unit.
    slope : float
        Estimate of ``-dg/dh`` (N/m, > 0) for the first bracket.

    Attributes
    ----------
    height : float
        The current iterate ``h_i`` of the pad's height (cumulative ``t_z``), m.
    plate : ndarray, shape (3,)
        The current iterate of the plate's in-plane pose ``(x, y, theta)``, m, rad
        (the commanded one for a rigid gripper).
    load_residual : float
        ``|g|`` after the last local solve, N.
    evaluations : int
        Local solves so far.
    failure : str
        Why the last load equation was not met ("" if it was).
    """

    def __init__(self, model: Model, state: State, command, scale: float, slope: float):
        self.model, self.state = model, state
        self.k = None if model.gripper.rigid else np.asarray(model.gripper.stiffness, dtype=float)
        self.start = float(state.upper_translation[2])
        # the commanded translation at height h: base + path (h - start)
        if isinstance(command, PadLoad):
            self.target, self.path = command.load, np.array([*command.retreat, 1.0])
            self.base, self.turn = np.array(state.upper_translation, dtype=float), float(state.upper_rotation)
            self.plate = np.array(state.plate, dtype=float)
            self.height = self.start  # the first iterate: the step's start, whose local problem is solved
        else:  # a commanded pose of a compliant gripper's plate, its height given
            translation, self.turn = commanded_pose(state, command)
            self.target, self.path = None, np.array([0.0, 0.0, 1.0])
            self.base = np.array([translation[0], translation[1], self.start])
            self.plate = np.array(state.plate) + [command.dx, command.dy, command.dtheta]
            self.height = float(translation[2])
        if self.k is None:
            self.plate = self.commanded()
        self.tol, self.scale, self.jump = LOAD_TOL * scale, scale, 0.0
        self.local_tol = min(model.options.local_tol, LOCAL_TOL)
        self.slope = slope
        n_lower = model.n_lower
        self.pad = np.arange(model.n_contacts) >= n_lower
        # the pad's start pose: the plate's, at the start height
        self.origin = replace(state, upper_translation=np.array([*state.plate[:2], self.start]),
                              upper_rotation=float(state.plate[2]))
        self.load_residual, self.evaluations, self.failure, self.noise = math.inf, 0, "", 0.0
        self.pressing = None  # the contact forces (n_contacts, 3) on the pressing side of the last jump

    def commanded(self) -> np.ndarray:
        """The commanded plate pose ``c = (x, y, theta)`` at the current height (on the release's path)."""
        t = self.base + self.path * (self.height - self.start)
        return np.array([t[0], t[1], self.turn])

    def pose(self) -> tuple[np.ndarray, float]:
        """The pad's pose: translation (3,), m (the plate's x, y at the current height), and rotation, rad."""
        return np.array([self.plate[0], self.plate[1], self.height]), float(self.plate[2])

    def commanded_translation(self) -> np.ndarray:
        """The commanded translation (3,) at the current height, m."""
        return self.base + self.path * (self.height - self.start)

    def kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """The pad's shift (3,), m, and its motion over the step at each contact (n_contacts, 3), m."""
        translation, rotation = self.pose()
        return translation, pad_motion(self.model, self.origin, translation, rotation)

    def _plate_columns(self) -> np.ndarray:
        """``B = du/dp`` (n_contacts, 3, 3) of the local kinematics by the plate's
        pose ``p = (x, y, theta)`` at the current iterate: ``-T dm/dp``, ``dm/dp``
        the pad point's motion (``e_x``, ``e_y``, and ``R'(theta - theta_0) rel``)."""
        model, n_lower = self.model, self.model.n_lower
        upper = model.contacts.nodes[n_lower:]
        rel = (model.mesh.nodes[upper] + self.state.displacement[upper])[:, :2] - model.upper_centre[:2] \
            - self.state.plate[:2]
        turn = self.plate[2] - self.state.plate[2]
        c, s = math.cos(turn), math.sin(turn)
        dm = np.zeros((upper.size, 3, 3))
        dm[:, 0, 0] = dm[:, 1, 1] = 1.0
        dm[:, :2, 2] = rel @ np.array([[-s, -c], [c, -s]]).T
        B = np.zeros((model.n_contacts, 3, 3))
        B[n_lower:] = -np.einsum("cij,cjk->cik", model.contacts.frames[n_lower:], dm)
        return B

    def solve(self, local_solve, q: np.ndarray, r: np.ndarray, w_mean: float, W: np.ndarray):
        """The local problem of a Newton iteration with the pad's unknowns
        (module docstring): ``local_solve(q, r_start, W)`` solves ``u = W r + q``
        (scaled by ``w_mean``, m/N, as in :mod:`fe_contact.stepping.newton`).
        A compliant gripper's plate is eliminated, ``p = c + k^-1 B^T r``:
        ``W + B k^-1 B^T``, ``q + B (c - p_i)``.  Returns the
        :class:`~fe_contact.contact.local_solver.LocalSolution` (its
        ``converged`` False if the load equation was not met), the ``q`` and
        the ``W`` it solved; sets :attr:`height` and :attr:`plate`."""
        B = self._plate_columns().reshape(-1, 3)
        b = (-self.model.contacts.frames[:, :, 2] * self.pad[:, None]).ravel() + B @ [*self.path[:2], 0.0]
        if self.k is not None:
            W = W + (B / self.k) @ B.T / w_mean
            q = q + (B @ (self.commanded() - self.plate)).reshape(-1, 3) / w_mean
        b = b.reshape(-1, 3) / w_mean
        zero = np.zeros_like(r)

        def solve(q_, start_, full=False):
            """Semismooth Newton warm from the last point, else from the iteration's forces, else from zero
            forces (warm from another height's stick / slip pattern it can cycle: measured on a pad 100 x
            the floor's); with ``full`` (the iteration's own problem, ``h = h_i``) then every method of a
            step (:func:`~fe_contact.stepping.newton._solve_contact`, the paper's Uzawa last)."""
            W_ = W if self.k is not None else None
            local = local_solve(q_, start_, W_, False, WARM_STALL)
            for again in ([r] if start_ is not r else []) + [zero]:
                if local.converged:
                    break
                local = local_solve(q_, again, W_, False, WARM_STALL if again is r else None)
            return local if local.converged or not full else local_solve(q_, r, W_, True)

        if self.target is None:
            local, q = self._done(solve(q, r, True), 0.0, 0.0, q, b, B)
            return local, q, W
        local, q_solved = self._solve_load(solve, q, r, b, B)
        return local, q_solved, W

    def _solve_load(self, local_solve, q, r, b, B):
        """The load equation's root in the height (module docstring)."""
        start, first = r, self.evaluations
        self.cap = first + MAX_LOAD_EVALUATIONS

        def at(dh, warm=None):
            nonlocal start
            local = local_solve(q + b * dh, start if warm is None else warm, dh == 0.0)
            self.evaluations += 1
            if local.converged:
                start = local.r
                self.noise = max(self.noise, _load_noise(local, q + b * dh, self.pad, self.local_tol))
            return local, float(local.r[self.pad, 0].sum()) - self.target

        pressing = self.pressing if self.jump else None  # the last iteration ended past a jump
        self.noise = self.jump = 0.0
        local, g = at(0.0)
        if not local.converged or abs(g) <= self.tolerance:
            return self._done(local, g, 0.0, q, b, B)
        best = self._still_past_jump(at, local, g, pressing) if pressing is not None and g < 0 else None
        if best is not None:
            return self._done(*best, q, b, B)
        best = self._bracket(at, local, g)
        if best is None:
            return self._done(local, g, 0.0, q, b, B, "no height found where the pad carries the load")
        return self._done(*best, q, b, B)

    def _still_past_jump(self, at, local, g, pressing):
        """``(local, g, 0)`` if the jump the last iteration ended past is still
        just below the current height ``h_i`` (its load below the target there):
        the pad presses too hard ``JUMP_WIDTH |h_i|`` lower (one local solve,
        warm from the last jump's pressing side), the bracket a jump by
        :meth:`_illinois`'s own test; else None (the full bracket follows).
        Without it each Newton iteration of a step that ends past a jump
        searched the jump again from a bracket of the load over the slope
        (about 16 local solves, some that no method solves: a pad 100 x the
        floor's spent 41 of its 42 s release in one such step's 10 iterations)."""
        dh = -JUMP_WIDTH * abs(self.height)
        if dh == 0.0:
            return None
        below, g_below = at(dh, pressing)
        if not below.converged or g_below <= self.tolerance:
            return None
        self.jump, self.pressing = g_below - g, below.r
        return local, g, 0.0

    def _bracket(self, at, local, g):
        """``(local, g, dh)`` at a root of ``g`` (or the best point when the
        solves or the evaluations ran out), or None without a sign change.
        A probe that no local method solves is too far: the step is shortened
        (by 4), and after ``MAX_FAILED_PROBES`` such probes the bracket is
        given up (None: the iteration fails and the step is split).  Without
        that bound a pad 10 x the floor's crept towards a height beyond which
        no local solve converged, the load still above its target, every
        other probe failing, each failure 3-4 s (every method, the paper's
        Uzawa up to 20000 iterations): 211 of its 221 s release in 4 load steps."""
        lo = hi = None  # (dh, g, local): g > 0 at lo (the pad presses too hard), g < 0 at hi
        failed = 0  # probes that no local method solved
        point = (0.0, g, local)
        step = g / self.slope
        while self.evaluations < self.cap:
            dh, g, local = point
            if g > 0:
                lo = point
            else:
                hi = point
            if lo is not None and hi is not None:
                break
            local, g = at(dh + step)
            if not local.converged:  # too far for the local solvers: a shorter step from the last good point
                failed += 1
                if failed >= MAX_FAILED_PROBES:
                    return None
                step /= 4.0
                continue
            point = (dh + step, g, local)
            if abs(g) <= self.tolerance:
                return local, g, dh + step
            step *= 2.0
        else:
            return None
        return self._illinois(at, lo, hi)

    def _illinois(self, at, lo, hi):
        """Regula falsi between ``lo`` and ``hi`` with the Illinois halving of a
        kept end's value, and a bisection when three steps did not halve the
        bracket (a flat end, the pad open: regula falsi creeps there), until
        ``|g| <= tol`` or the bracket's values differ by noise.  A point that
        no local method solves is replaced by the point half way to an end
        (the pressing end first), up to ``MAX_FAILED_PROBES`` such points
        (giving up at the first one left a pad 100 x the floor's, released in
        6 load steps, unsettled: its last step bracketed the pad's opening and
        one local solve inside the bracket failed)."""
        (a, ga, la), (c, gc, lc) = lo, hi
        fa, fc = ga, gc  # the values regula falsi uses (Illinois halves a kept end's)
        side, widths, failed, retry = 0, [abs(c - a)] * 3, 0, None
        while self.evaluations < self.cap:
            if abs(c - a) <= JUMP_WIDTH * (abs(self.height) + abs(a) + abs(c)):
                # the load jumps across its target at one height (the pad lets go at once): the step ends
                # past the jump, its load below the target (the schedule goes on from there)
                self.jump, self.pressing = abs(ga - gc), la.r
                return lc, gc, c
            x = retry if retry is not None else \
                0.5 * (a + c) if abs(c - a) > 0.5 * widths[-3] else a - fa * (c - a) / (fc - fa)
            local, g = at(x)
            retry = None
            if not local.converged:  # half way to an end instead, the ends in turn, MAX_FAILED_PROBES in all
                failed += 1
                if failed >= MAX_FAILED_PROBES:
                    break
                retry = 0.5 * (x + (a if failed % 2 else c))
                continue
            if abs(g) <= self.tolerance or abs(ga - gc) <= 2 * self.tolerance:  # solved, or the bracket is noise
                self._secant(a, ga, c, gc)
                return local, g, x
            if g > 0:
                a, ga, la, fa = x, g, local, g
                fc = fc / 2 if side == 1 else fc
                side = 1
            else:
                c, gc, lc, fc = x, g, local, g
                fa = fa / 2 if side == -1 else fa
                side = -1
            widths.append(abs(c - a))
        best = min((ga, la, a), (gc, lc, c), key=lambda p: abs(p[0]))
        return best[1], best[0], best[2]

    @property
    def tolerance(self) -> float:
        """``|g|`` allowed, N: ``LOAD_TOL`` of the load scale, or the local solves' own error of the pad's load
        (at most ``NOISE_CAP`` of the scale)."""
        return max(self.tol, min(self.noise, NOISE_CAP * self.scale))

    def _secant(self, a, ga, c, gc):
        """Keep the bracket's slope ``-dg/dh`` for the next iteration's first step."""
        if c != a and (ga - gc) / (c - a) > 0:
            self.slope = (ga - gc) / (c - a)

    def _done(self, local, g, dh, q, b, B, failure=""):
        """Move to the height found and the plate's pose ``c + k^-1 B^T r``; a
        local solve that failed is the Newton loop's to report."""
        self.height += dh
        if self.k is not None and local.converged:
            self.plate = self.commanded() + (B.T @ local.r.ravel()) / self.k
        elif self.k is None:
            self.plate = self.commanded()
        self.load_residual = abs(g)
        self.failure = ""
        if local.converged and abs(g) > self.tolerance and not (self.jump and g < 0):
            self.failure = failure or (f"the pad's load equation not met: |g| = {abs(g):.3g} N > {self.tolerance:.3g} N "
                                       f"after {self.evaluations} local solves")
            local = replace(local, converged=False)
        return local, q + b * dh


def load_step(model: Model, state: State, command, t0: float, local_problem_hook=None, guess=None):
    """The Newton loop of a step with the pad's unknowns (a :class:`PadLoad`, or
    a compliant gripper's commanded pose) from ``state`` (the block where it
    is) and its report, whose ``command`` is the commanded motion the step
    found, ``gripper_force`` the spring force ``k (c - p)`` of a compliant
    gripper and ``plate`` its pose.  Returns ``(eq, report, translation,
    rotation, plate)``, the commanded pose and the plate's.

    ``guess`` (a :class:`PadLoad`'s, :func:`~fe_contact.stepping.predictor.load_path_guess`)
    starts the loop at its displacements, contact forces and pad height; the step's
    force scale (its convergence test) is the one from the state; if the loop does
    not converge from the guess, the step is solved again from the state (the
    report counts both loops' iterations).  Its Newton tolerance: :func:`path_tolerance`."""
    lx, ly, lz = model.mesh.size
    current = pad_normal_load(model, state)
    target = command.load if isinstance(command, PadLoad) else 0.0
    drive = LoadDrive(model, state, command, max(target, current, model.weight), model.material.young * lx * ly / lz)
    loading = pad_loading(model, state)
    guess = guess if isinstance(command, PadLoad) else None
    U = guessed_start(model, state, command, guess)
    if guess is not None and guess.height is not None:
        drive.height = guess.height
    eq = equilibrium(model, state, U, local_problem_hook, False, loading, drive, guess=guess,
                     scale_at=None if guess is None else state.displacement, path_tol=path_tolerance(model, command))
    if guess is not None and eq.status is not Status.CONVERGED:  # the guess misled it: from the state
        again, report, *pose = load_step(model, state, command, t0, local_problem_hook)
        return again, replace(report, newton_iterations=report.newton_iterations + len(eq.iterations)), *pose
    translation, c = drive.commanded_translation(), drive.commanded()
    taken = Command(*(translation - state.upper_translation), c[2] - state.upper_rotation) \
        if isinstance(command, PadLoad) else command
    extra = None if drive.k is None else {"gripper_force": drive.k * (c - drive.plate), "plate": drive.plate.copy()}
    report = checked(model, measure(model, state, taken, eq, t0, loading, extra))
    return eq, report, translation, float(c[2]), drive.plate.copy()


def path_tolerance(model: Model, command) -> float | None:
    """``SolverOptions.path_tol`` for a :class:`PadLoad` to a load above zero (a point
    on the release's unloading path, whose discretisation error in the load steps is
    0.1-1 % of the lag: docs/release.md), else None (``newton_tol``: the release's
    last step to zero load, a compliant gripper's commanded pose).  The one place
    that decides which steps the path tolerance applies to (midpoint halves, second
    backward-Euler halves and split parts are PadLoads above zero too)."""
    return model.options.path_tol if isinstance(command, PadLoad) and command.load > 0 else None


def _load_noise(local, q: np.ndarray, pad: np.ndarray, local_tol: float) -> float:
    """What the local solve's tolerance leaves uncertain in the pad's load, N:
    ten times ``local_tol`` (a natural-map residual relative to ``max(|q|, |r|,
    |u|)``, :func:`~fe_contact.contact.local_solver.natural_map_residual`) in
    that scale, over the pad's normal rows (a sum of ``n_pad`` errors)."""
    scale = max(np.linalg.norm(q), np.linalg.norm(local.r), np.linalg.norm(local.u))
    return 10.0 * max(local_tol, local.residual) * scale * math.sqrt(pad.sum())


def pad_normal_load(model: Model, state: State) -> float:
    """The pad's normal load at ``state`` (the sum of its contacts' normal forces), N."""
    return float(state.reaction[model.n_lower:, 0].sum())
