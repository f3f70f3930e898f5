"""Anderson acceleration of the modified-Newton loop of a step
(:mod:`fe_contact.stepping.newton`).

With a tangent ``K0`` kept over the iterations, an iteration of the loop is the
map of the free-dof displacements ``x`` (n_free,), m,

    G(x) = x + K0^-1 p(x),    p(x) = C^T T^T r(x) - f(x),    N,

``f`` the internal minus applied force of the free dofs at ``x`` and ``r(x)``
(n_contacts, 3), N, the contact forces of the local solve of the problem
linearised at ``x`` (the iterate's own contact forces cancel out of ``q`` and of
the update, see the newton module).  Its fixed point is the step's solution; it
contracts linearly, by the mismatch ``I - K0^-1 K(x)`` of the kept tangent
(0.05-0.06 per iteration on the paper's case 3: the tangent of the undeformed
block against the pressed and sheared one).

Anderson's mixing (type II, undamped; Walker & Ni, SIAM J. Numer. Anal. 49 (2011)
1715, eq. 2.1 there with ``beta = 1``) takes as next iterate

    x_{k+1} = G(x_k) - dG gamma,    gamma = argmin |p(x_k) - dP gamma|_2,

``dG`` (n_free, m) and ``dP`` (n_free, m) the differences of consecutive ``G(x_j)``
and ``p(x_j)`` over the last ``m <= depth`` evaluations: a multisecant
quasi-Newton step (for a linear map, GMRES).  The least squares are taken on
``p``, in newtons: the out-of-balance force the iteration corrects, the units of
the convergence test.  The contact forces are mixed with the same weights,
``r_{k+1} = r(x_k) - dR gamma``: the warm start of the next local solve.

The differences stay valid as long as the tangent does: the next step's map has
the same ``K0`` and nearly the same Jacobian (the block changes little in a
step), so they are handed on with the tangent (:class:`SecantPairs`, immutable)
and a step's first mixes use its predecessors' (the last two pushes of the
paper's case 3 drop 230- and 1000-fold in their first mix, 18-fold in a plain
iteration).  The step's first correction, from the predictor, also settles the
contact statuses: it makes no difference pair (with it, the planner's rubber
rollouts took 258 iterations, without 216, unaccelerated 244).

A mixed iterate is a trial point of ``G`` only.  Its contact forces need not
satisfy De Saxce's law (the weights extrapolate: a mix can leave the cone), so
the loop never declares convergence at one; it goes back to the plain iterate
``G(x_k)`` when a mix does not lower the out-of-balance force or breaks down
(an inverted element, a failed contact solve), and forgets the differences.
A tangent refreshed at an iterate (nearly Newton's: the next plain iterate
passes) ends the mixing for the step; full Newton and the frictional pad's
proximal springs (a map that changes every iteration) are not mixed.
"""

from __future__ import annotations

import numpy as np

_RCOND = 1e-10
"""Relative singular value below which a direction of the differences is dropped
from the least squares (the columns are normalised first)."""


class SecantPairs:
    """The differences ``dG`` (m), ``dP`` (N) and ``dR`` (N) of the last
    evaluations of ``G`` with one tangent, each pair of columns divided by the
    norm of its ``dP`` column (so that the least squares are well scaled).

    Immutable (tuples of arrays never written): a state's cached tangent keeps
    one, and the steps branched from the state share it.
    """

    __slots__ = ("dg", "dp", "dr")

    def __init__(self, dg: tuple = (), dp: tuple = (), dr: tuple = ()):
        self.dg, self.dp, self.dr = dg, dp, dr

    def __len__(self) -> int:
        return len(self.dp)

    def added(self, dg: np.ndarray, dp: np.ndarray, dr: np.ndarray, depth: int) -> "SecantPairs":
        """These pairs and one more, the oldest dropped beyond ``depth``."""
        norm = float(np.linalg.norm(dp))
        if not norm > 0 or not np.isfinite(norm):
            return self
        keep = slice(max(0, len(self) + 1 - depth), None)
        return SecantPairs((self.dg + (dg / norm,))[keep], (self.dp + (dp / norm,))[keep],
                           (self.dr + (dr / norm,))[keep])


class Anderson:
    """Anderson mixing over the iterations of one step.

    Parameters
    ----------
    depth : int
        Differences kept, >= 1.
    pairs : SecantPairs, optional
        Those of the earlier steps with the same tangent.

    Attributes
    ----------
    pairs : SecantPairs
        The differences so far (for the tangent the step hands on).
    mixed : bool
        The current iterate is a mix (its contact forces need not satisfy the law).
    """

    def __init__(self, depth: int, pairs: SecantPairs | None = None):
        self.depth = depth
        self.pairs = pairs if pairs is not None else SecantPairs()
        self.mixed = False
        self._mixing = True
        self._first = True  # the step's first evaluation is to come
        self._last = None  # (G(x), p(x), r(x)) of the step's previous evaluation
        self._plain = None  # (U, r): the plain iterate the current mix replaced

    def restart(self, mixing: bool = True) -> None:
        """Forget the differences (a new tangent: another map); with ``mixing``
        False, mix no more in this step (a tangent taken at an iterate converges
        nearly as Newton's, and only a plain iterate can pass the test)."""
        self.pairs, self._last = SecantPairs(), None
        self._mixing = self._mixing and mixing

    def fall_back(self) -> tuple[np.ndarray, np.ndarray]:
        """The plain iterate ``(U, r)`` the current mix replaced; the differences forgotten."""
        U, r = self._plain
        self.restart()
        self.mixed, self._plain = False, None
        return U, r

    def next_iterate(self, U_plain: np.ndarray, r_plain: np.ndarray, free: np.ndarray, p: np.ndarray,
                     plain: bool) -> tuple[np.ndarray, np.ndarray]:
        """The iterate after the evaluation ``G(x) = U_plain[free]``.

        ``U_plain`` (n_nodes, 3), m, and ``r_plain`` (n_contacts, 3), N, are the
        plain iterate ``G(x)`` and its contact forces, ``p`` (n_free,), N, is
        ``p(x)`` at the point ``x`` it came from.  With ``plain`` (or no
        differences yet) the plain iterate is returned, else the mix.
        """
        g = U_plain.ravel()[free]
        r = r_plain.ravel()
        if self._last is not None:
            g0, p0, r0 = self._last
            self.pairs = self.pairs.added(g - g0, p - p0, r - r0, self.depth)
        # the step's first correction, from the predictor, also settles the contact
        # statuses: its difference to the next is no secant of the map near the solution
        self._last = None if self._first else (g.copy(), p, r.copy())
        self._first = False
        self.mixed = self._mixing and not plain and len(self.pairs) > 0
        if not self.mixed:
            self._plain = None
            return U_plain, r_plain
        self._plain = (U_plain, r_plain)
        dP = np.column_stack(self.pairs.dp)
        gamma = np.linalg.lstsq(dP, p, rcond=_RCOND)[0]
        U = U_plain.copy()
        U.ravel()[free] = g - np.column_stack(self.pairs.dg) @ gamma
        r_mix = (r - np.column_stack(self.pairs.dr) @ gamma).reshape(r_plain.shape)
        return U, r_mix
