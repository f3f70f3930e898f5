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
opening is a root: the block's state does not depend on which.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .command import Command, PadLoad
from .held import pad_loading, pad_motion
from .measure import measure
from .model import Model, State
from .newton import equilibrium

__all__ = ["LoadDrive", "LOAD_TOL", "MAX_LOAD_EVALUATIONS", "load_step"]

LOAD_TOL = 1e-10
"""The pad's load equation is met to this fraction of the load scale (the loaded pad load, or the weight)."""
LOCAL_TOL = 1e-13
"""The local solves of a load equation meet this natural-map residual (or ``local_tol`` if tighter): a warm start
within a looser tolerance returns the start unchanged, and the pad's load is then a staircase of the height."""
MAX_LOAD_EVALUATIONS = 60
"""Local solves of one Newton iteration's load equation at most (bracket and Illinois together)."""


class LoadDrive:
    """The pad's height as an unknown of a step's Newton loop (module docstring).

    Parameters
    ----------
    model : Model
        With a frictional pad.
    state : State
        The step's start (its pad pose ``t_0``, rotation kept).
    command : PadLoad
        The load ``P`` at the end of the step and the path's retreat.
    scale : float
        Load scale, N (the loaded pad load, or the weight): the tolerance's unit.
    slope : float
        Estimate of ``-dg/dh`` (N/m, > 0) for the first bracket.

    Attributes
    ----------
    height : float
        The current iterate ``h_i`` of the pad's height (cumulative ``t_z``), m.
    load_residual : float
        ``|g|`` after the last local solve, N.
    evaluations : int
        Local solves so far.
    failure : str
        Why the last load equation was not met ("" if it was).
    """

    def __init__(self, model: Model, state: State, command: PadLoad, scale: float, slope: float):
        self.model, self.state, self.target = model, state, command.load
        self.path = np.array([*command.retreat, 1.0])
        self.start = float(state.upper_translation[2])
        self.tol = LOAD_TOL * scale
        self.local_tol = min(model.options.local_tol, LOCAL_TOL)
        self.slope = slope
        n_lower = model.n_lower
        self.pad = np.arange(model.n_contacts) >= n_lower
        b = np.zeros((model.n_contacts, 3))
        b[n_lower:] = -model.contacts.frames[n_lower:] @ self.path
        self.b = b
        self.height = self.start  # the first iterate: the step's start, whose local problem is solved
        self.load_residual, self.evaluations, self.failure = math.inf, 0, ""

    def pose(self) -> tuple[np.ndarray, float]:
        """The pad's pose at the current height: translation (3,), m, and rotation, rad."""
        return self.state.upper_translation + self.path * (self.height - self.start), self.state.upper_rotation

    def kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """The pad's shift (3,), m, and its motion over the step at each contact (n_contacts, 3), m."""
        translation, rotation = self.pose()
        return translation, pad_motion(self.model, self.state, translation, rotation)

    def solve(self, local_solve, q: np.ndarray, r: np.ndarray, w_mean: float):
        """The local problem of a Newton iteration with the load equation
        (module docstring): ``local_solve(q, r_start)`` solves ``u = W r + q``
        (scaled by ``w_mean``, m/N, as in :mod:`fe_contact.stepping.newton`).
        Returns the :class:`~fe_contact.contact.local_solver.LocalSolution` at
        the height found (its ``converged`` False if the load equation was not
        met) and the ``q`` it solved; sets :attr:`height`."""
        b = self.b / w_mean
        start, first = r, self.evaluations
        self.cap = first + MAX_LOAD_EVALUATIONS

        def at(dh):
            nonlocal start
            local = local_solve(q + b * dh, start)
            self.evaluations += 1
            if local.converged:
                start = local.r
                self.noise = max(self.noise, _load_noise(local, q + b * dh, self.pad, self.local_tol))
            return local, float(local.r[self.pad, 0].sum()) - self.target

        self.noise = 0.0

        local, g = at(0.0)
        if not local.converged or abs(g) <= self.tolerance:
            return self._done(local, g, 0.0, q, b)
        best = self._bracket(at, local, g)
        if best is None:
            return self._done(local, g, 0.0, q, b, "no height found where the pad carries the load")
        return self._done(*best, q, b)

    def _bracket(self, at, local, g):
        """``(local, g, dh)`` at a root of ``g`` (or the best point when the
        solves or the evaluations ran out), or None without a sign change."""
        lo = hi = None  # (dh, g, local): g > 0 at lo (the pad presses too hard), g < 0 at hi
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
        kept end's value, until ``|g| <= tol`` or the bracket is rounding."""
        (a, ga, la), (c, gc, lc) = lo, hi
        side = 0
        while self.evaluations < self.cap:
            x = a - ga * (c - a) / (gc - ga)
            local, g = at(x)
            if not local.converged:
                break
            if abs(g) <= self.tolerance or abs(ga - gc) <= 2 * self.tolerance:  # solved, or the bracket is noise
                self._secant(a, ga, c, gc)
                return local, g, x
            if g > 0:
                a, ga, la = x, g, local
                gc = gc / 2 if side == 1 else gc
                side = 1
            else:
                c, gc, lc = x, g, local
                ga = ga / 2 if side == -1 else ga
                side = -1
        best = min((ga, la, a), (gc, lc, c), key=lambda p: abs(p[0]))
        return best[1], best[0], best[2]

    @property
    def tolerance(self) -> float:
        """``|g|`` allowed, N: ``LOAD_TOL`` of the load scale, or the local solves' own error of the pad's load."""
        return max(self.tol, self.noise)

    def _secant(self, a, ga, c, gc):
        """Keep the bracket's slope ``-dg/dh`` for the next iteration's first step."""
        if c != a and (ga - gc) / (c - a) > 0:
            self.slope = (ga - gc) / (c - a)

    def _done(self, local, g, dh, q, b, failure=""):
        """Move to the height found; a local solve that failed is the Newton loop's to report."""
        self.height += dh
        self.load_residual = abs(g)
        self.failure = ""
        if local.converged and abs(g) > self.tolerance:
            self.failure = failure or (f"the pad's load equation not met: |g| = {abs(g):.3g} N > {self.tolerance:.3g} N "
                                       f"after {self.evaluations} local solves")
            local = replace(local, converged=False)
        return local, q + b * dh


def load_step(model: Model, state: State, command: PadLoad, t0: float, local_problem_hook=None):
    """The Newton loop of a pad load step from ``state`` (the block where it
    is, the pad's height from the block's axial stiffness ``E A / H``) and its
    report, whose ``command`` is the pad's motion the step found.  Returns
    ``(eq, report, translation, rotation)``."""
    lx, ly, lz = model.mesh.size
    current = float(state.reaction[model.n_lower:, 0].sum())
    scale = max(command.load, current, model.weight)
    drive = LoadDrive(model, state, command, scale, model.material.young * lx * ly / lz)
    loading = pad_loading(model, state)
    eq = equilibrium(model, state, np.array(state.displacement, dtype=float), local_problem_hook, False, loading,
                     drive)
    translation, rotation = drive.pose()
    taken = Command(*(translation - state.upper_translation))
    return eq, measure(model, state, taken, eq, t0, loading), translation, rotation


def _load_noise(local, q: np.ndarray, pad: np.ndarray, local_tol: float) -> float:
    """What the local solve's tolerance leaves uncertain in the pad's load, N:
    ten times ``local_tol`` (a natural-map residual relative to ``max(|q|, |r|,
    |u|)``, :func:`~fe_contact.contact.local_solver.natural_map_residual`) in
    that scale, over the pad's normal rows (a sum of ``n_pad`` errors)."""
    scale = max(np.linalg.norm(q), np.linalg.norm(local.r), np.linalg.norm(local.u))
    return 10.0 * max(local_tol, local.residual) * scale * math.sqrt(pad.sum())
