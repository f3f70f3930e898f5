"""Factorised free-dof tangent and the flexibility matrix (paper sect. 8), and
the policy of when a step builds a new one.

The flexibility matrix is the contact block of the inverse tangent, in the
local frames:

    W = T C K_ff^-1 C^T T^T,    shape (3 n_contacts, 3 n_contacts), m/N,

with ``C`` picking the contact dofs out of the free ones and ``T`` the
world-to-local rotation of each contact node.  It is kept divided by its mean
diagonal ``w_mean`` (``W_scaled``, dimensionless), so that ``u = W r + q`` has
force units in the local solver.

Policy (modified Newton, ``SolverOptions.reuse_tangent``): a tangent is taken
at the converged start of a step and kept over its iterations and the next
steps; it is refreshed when the out-of-balance force contracts by less than
``refresh_ratio`` per iteration and a new one pays for itself
(:func:`refresh_pays`, a size-based cost model).  A tangent at an iterate that
is not positive definite is replaced by the one at the start of the step
(:func:`refreshed_tangent`).  A factorisation or flexibility matrix that breaks
down is returned as a message, never raised.
"""

from __future__ import annotations

import copy
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse.linalg as spla

from ..linalg.threads import dense_kernel, dense_threads
from ..linalg.cholesky import NotPositiveDefinite, SupernodalFactor, factorise
from ..fem.elasticity import internal_force_and_tangent
from ..fem.loads import NO_LOADING
from ..contact.local_solver import NewtonWorkspace
from .model import Model, State

_THREADED_WORK = 2_000_000  # right-hand sides x free dofs above which W is computed on threads
_RHS_BLOCK_ENTRIES = 25_000_000  # right-hand sides x free dofs solved at once for W on SuperLU (200 MB)

# Cost model of a tangent against a modified-Newton iteration, in seconds on the
# CI-class CPU (fitted to benchmarks/paper_case.py, planning_step.py and
# scaling.py to within 2x).  It only decides whether refreshing the tangent
# pays; being a function of sizes, not of timings, it keeps runs bitwise
# repeatable.
_S_PER_GAUSS_POINT = 2.6e-7  # internal forces of one Gauss point
_S_PER_TANGENT_POINT = 3e-6  # tangent stiffness of one Gauss point
_SPARSE_FLOPS = 1.4e9  # flop/s of one sparse triangular solve pair (one thread)
_SPARSE_W_FLOPS = 6e9  # flop/s of the SuperLU multi-right-hand-side solves for W (two threads)
_FACTOR_SOLVES = 60  # a SuperLU factorisation costs about this many solves
_DENSE_FLOPS = 2e10  # flop/s of the multifrontal factorisation (BLAS 3)
_LOCAL_PRODUCTS = 30  # products with W (GMRES on old LU factors) in the local solve of an iteration
_FRESH_RATE = 0.05  # contraction per iteration with a fresh tangent (measured 0.03-0.05)
_ITERATION_OVERHEAD_S = 4e-3  # interpreter work of an iteration (local solver loop), planning mesh


def factorise_free(K, free: np.ndarray, order: np.ndarray | None = None):
    """SuperLU factors of ``K[free][:, free]``, its rows and columns taken in
    ``order`` (positions in ``free``) if given.

    With an order, SuperLU keeps it and works in symmetric mode (diagonal
    pivots unless one is below 0.01 of its column, the tangent being
    symmetric); without, it orders by minimum degree on ``K + K^T``.
    Raises RuntimeError if the matrix is singular.
    """
    if order is None:
        return spla.splu(K[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A")
    ordered = free[order]
    return spla.splu(K[ordered][:, ordered].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.01,
                     options={"SymmetricMode": True})


class LUFactor:
    """SuperLU factors of ``K_ff`` with the solve interface of
    :class:`~fe_contact.linalg.cholesky.SupernodalFactor` (for an indefinite tangent
    or a mesh that is not a tensor grid)."""

    def __init__(self, K, free: np.ndarray, order: np.ndarray | None):
        self.lu = factorise_free(K, free, order)
        self.order = order
        self.nnz = self.lu.nnz

    def solve(self, rhs_free: np.ndarray) -> np.ndarray:
        if self.order is None:
            return self.lu.solve(rhs_free)
        x = np.empty_like(rhs_free)
        x[self.order] = self.lu.solve(rhs_free[self.order])
        return x


class Tangent:
    """Factorised free-dof tangent and the flexibility matrix derived from it.

    ``W`` is the contact block of ``K_ff^-1``.  On a tensor-grid mesh the
    tangent is factorised by the multifrontal Cholesky of
    :mod:`fe_contact.linalg.cholesky`, which eliminates the contact dofs last, so
    ``W`` is the inverse of the Schur complement it leaves (no solves with
    one right-hand side per contact dof).  If the tangent is not positive
    definite, or the mesh is not a grid, SuperLU factorises it and ``K_ff^-1``
    is applied to one unit vector per contact dof, on
    :func:`~fe_contact.linalg.threads.dense_threads` threads (SuperLU releases the GIL).
    With ``lu_fallback=False`` a grid mesh's tangent that is not positive
    definite raises :class:`~fe_contact.linalg.cholesky.NotPositiveDefinite` instead.

    Attributes
    ----------
    W_scaled : ndarray, shape (3 n_contacts, 3 n_contacts)
        ``W / w_mean``, local frames, dimensionless.
    w_mean : float
        Mean diagonal compliance of ``W``, m/N.
    build_s, iteration_s : float
        Estimated seconds to build this tangent and of one Newton iteration with it.
    """

    def __init__(self, model: Model, K, lu_fallback: bool = True):
        free = model.free_dofs
        n_lower = model.n_contacts
        # Positions of the contact dofs (x, y, z per node) inside the free-dof vector.
        self.contact_index = np.searchsorted(free, model.contact_dofs.ravel())
        self.n_free = free.size
        m = 3 * n_lower
        structure = model.factor_structure
        n_points = model.geometry.dvol.size
        G = None
        if structure is not None:
            try:
                with dense_kernel(structure.max_front):
                    self.factor = factorise(structure, K.data)
                    G = self.factor.root_inverse()  # contact dofs in contact_dofs order
                self.method = "multifrontal"
                build_s = (structure.flops + m**3) / _DENSE_FLOPS
            except NotPositiveDefinite:
                if not lu_fallback:
                    raise
                G = None
        if G is None:
            self.factor = LUFactor(K, free, None if structure is None else structure.perm)
            self.method = "superlu"
            G = self._sparse_compliance(n_lower)
            G = 0.5 * (G + G.T)  # exact symmetry
            build_s = _FACTOR_SOLVES * 2.0 * self.factor.nnz / _SPARSE_FLOPS + m * 2.0 * self.factor.nnz / _SPARSE_W_FLOPS
        # estimated seconds (see refresh_pays)
        solve_s = 4.0 * self.factor.nnz / _SPARSE_FLOPS
        local_s = _LOCAL_PRODUCTS * 2.0 * float(m) ** 2 / _SPARSE_FLOPS
        self.build_s = n_points * _S_PER_TANGENT_POINT + build_s
        solves = 1.0 if self.method == "multifrontal" else 2.0  # per iteration (solve_with_contact)
        self.iteration_s = _ITERATION_OVERHEAD_S + n_points * _S_PER_GAUSS_POINT + solves * solve_s + local_s
        # to the local frames, W = T G T^T (T block diagonal), in place a band
        # of rows at a time (no second matrix of W's size)
        W = G
        model.contacts.rotate_blocks(W)
        # Divided by its mean diagonal compliance, u = W r + q has force units, so
        # the natural-map residual (r - proj(r - modified(u))) is homogeneous; the
        # contact law is invariant under this scaling of u.  Kept scaled, once.
        self.w_mean = float(np.mean(np.diag(W)))
        W /= self.w_mean
        self.W_scaled = W
        # the local Newton matrix factorised in one iteration serves the next ones;
        # a step works on a copy, so that stepping twice from one state agrees
        self.workspace = NewtonWorkspace()
        # the Anderson differences of the modified-Newton map with this tangent
        # (fe_contact.stepping.acceleration.SecantPairs), handed on like the workspace
        self.secants = None

    def _sparse_compliance(self, n_lower: int) -> np.ndarray:
        def contact_block(cols):
            E = np.zeros((self.n_free, cols.size))
            E[self.contact_index[cols], np.arange(cols.size)] = 1.0
            return self.solve(E)[self.contact_index]

        m = 3 * n_lower
        # right-hand sides a block at a time: all at once is n_free x m
        # (15 GB at 2.3e5 dofs)
        blocks = np.array_split(np.arange(m), max(1, -(-m * self.n_free // _RHS_BLOCK_ENTRIES)))
        threads = dense_threads()
        if threads == 1 or m * self.n_free < _THREADED_WORK:  # small: threads cost more than they save
            return np.hstack([contact_block(cols) for cols in blocks])
        with ThreadPoolExecutor(threads) as pool:
            return np.hstack(list(pool.map(contact_block, blocks)))

    def with_workspace(self, workspace: NewtonWorkspace, secants=None) -> "Tangent":
        other = copy.copy(self)
        other.workspace, other.secants = workspace, secants
        return other

    def solve(self, rhs_free: np.ndarray) -> np.ndarray:
        """``K_ff^-1 rhs`` for one right-hand side (n_free,) or several (n_free, k)."""
        return self.factor.solve(rhs_free)

    def solve_with_contact(self, rhs_free: np.ndarray):
        """Begin ``K_ff^-1 (rhs + C^T f)`` for contact-node forces ``f`` not
        known yet, for one right-hand side (n_free,) or several (n_free, k).

        Returns the contact-node displacements of ``K_ff^-1 rhs`` (n_lower, 3)
        or (n_lower, 3, k) and a function of ``f`` (shaped like them, world
        frame) that returns the whole solution (n_free,) or (n_free, k).  On
        the multifrontal factor this is one forward and one backward
        substitution in all: the contact dofs are eliminated last, so ``f``
        changes only the root block of the forward pass.  On SuperLU it is two
        solves.
        """
        rhs_free = np.asarray(rhs_free, dtype=float)
        k = rhs_free.shape[1:]
        if isinstance(self.factor, SupernodalFactor):
            factor = self.factor
            y = factor.forward(rhs_free)
            contact = factor.root_backward(y)  # (3 n_lower, k or 1)

            def finish(force_world):
                y[-contact.shape[0]:] += factor.root_forward(force_world.reshape(contact.shape))
                return factor.backward(y).reshape(rhs_free.shape)

            return contact.reshape(-1, 3, *k), finish
        x = self.solve(rhs_free)

        def finish_lu(force_world):
            rhs = np.zeros_like(rhs_free)
            rhs[self.contact_index] = force_world.reshape(-1, *k)
            return x + self.solve(rhs)

        return x[self.contact_index].reshape(-1, 3, *k), finish_lu


REFRESH_HORIZON = 30
"""Iterations within which a kept tangent must converge, else it is refreshed (the Newton cap before issue 39)."""


def refresh_pays(tangent: Tangent, rate: float, rel_res: float, opts, it: int) -> bool:
    """Whether a new tangent saves more iterations than it costs.

    At contraction ``rate`` per iteration, reaching ``newton_tol`` from
    ``rel_res`` takes ``log(tol / res) / log(rate)`` iterations, with a fresh
    tangent about ``log(tol / res) / log(_FRESH_RATE)``.  A tangent that does
    not contract, or would not converge within ``newton_max_iter`` (at most
    :data:`REFRESH_HORIZON`), is always refreshed.
    """
    if rate >= 1.0:
        return True
    gap = math.log(opts.newton_tol / rel_res)
    needed = gap / math.log(rate)
    if it + needed > min(opts.newton_max_iter, REFRESH_HORIZON):
        return True
    saved = needed - gap / math.log(_FRESH_RATE)
    return saved * tangent.iteration_s > tangent.build_s


def refresh_due(tangent: Tangent, at_start: bool, it: int, rel_res: float, prev_res: float, opts,
                mixed: bool = False) -> bool:
    """Whether the reused ``tangent`` contracts too slowly at iteration ``it``
    (relative out-of-balance force ``prev_res`` -> ``rel_res``) and a new one pays.

    Never after a fallback to the start-state tangent (``at_start``: another
    would come back to the same tangent), nor before iteration 2 (the first
    correction of a step also settles the contact statuses, so its contraction
    says little about the tangent).  At an Anderson mix (``mixed``,
    :mod:`fe_contact.stepping.acceleration`) the contraction is the mixing's, which
    stays below ``refresh_ratio`` where the tangent's own is above (a Neo-Hookean
    block: 0.1-0.18 mixed, 0.21 plain): there the cost model alone decides.
    """
    return (not at_start and it >= 2 and (mixed or rel_res > opts.refresh_ratio * prev_res)
            and refresh_pays(tangent, rel_res / prev_res, rel_res, opts, it))


def refreshed_tangent(model: Model, state: State, handed_K: list, it: int, timings: dict, loading=None):
    """A new tangent from the stiffness ``K`` (n_dofs, n_dofs) in ``handed_K``.

    ``K`` is at the current iterate, or at the step's start at iteration 0 of a
    step with ``reuse_tangent``.  At an iterate it may be indefinite: an
    iterate can strain the top layer past St Venant-Kirchhoff's stable range
    in compression (E = -0.49, det F = 0.2 at 2.3e5 dofs); then the tangent at
    the converged start of the step is taken instead, as a step without a
    cached tangent does.  ``handed_K`` is a one-element list the caller gives
    up, so that ``K`` goes before the start-state one is assembled.
    ``loading`` (:class:`~fe_contact.fem.loads.Loading`) adds its springs to the
    start-state stiffness.

    Returns
    -------
    tangent : Tangent or None
        None if it broke down.
    at_start : bool
        The tangent was taken at the start state as a fallback.
    failure : str
        Why it broke down (singular factorisation, flexibility matrix not
        positive definite), or "".
    """
    try:
        try:
            tangent = Tangent(model, handed_K.pop(), lu_fallback=it == 0 and model.reuses_tangent)
        except NotPositiveDefinite:
            tangent = None  # K and its partial factors go with the exception
        at_start = tangent is None
        if at_start:
            t0 = time.perf_counter()
            if loading is None:
                _, K, _ = internal_force_and_tangent(model.geometry, model.mesh.elements, state.displacement,
                                                     model.material, model.pattern)
            else:
                _, K, _ = loading.tangent(model, state.displacement)
            dt = time.perf_counter() - t0
            timings["assembly"] += dt
            timings["tangent"] -= dt  # (the caller times this call as tangent time)
            tangent = Tangent(model, K)
    except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
        return None, False, f"tangent stiffness singular at Newton iteration {it}: {exc}"
    if _flexible(tangent):
        return tangent, at_start, ""
    tangent, at_start = _supported_tangent(model, state, loading, timings), True
    w_diag = np.diag(tangent.W_scaled)
    if not _flexible(tangent):
        # a flexibility matrix must be positive definite; rounding has won
        # (e.g. nearly incompressible material, nu -> 0.5)
        return None, at_start, (
            f"flexibility matrix not positive definite at Newton iteration {it} "
            f"(min scaled diagonal {w_diag.min():.3g}): tangent stiffness too ill-conditioned"
        )
    return tangent, at_start, ""


def _supported_tangent(model: Model, state: State, loading, timings: dict) -> Tangent:
    """The start-state tangent with a spring on every contact dof, for a
    block that is unstable held by its upper face alone.

    ``K_ff`` leaves the contact dofs free: it is the stiffness of the block
    hanging from its upper face, which a compressive force past about
    ``G A`` (shear buckling of the free block) makes indefinite although the
    floor holds the block.  Springs ``k`` (the mean diagonal stiffness of
    the contact dofs) stand in for the floor: with ``K + k C^T C`` instead of
    ``K`` Newton's out-of-balance force after an update is ``-k C^T C dU``, nil
    at the contact nodes the contact law fixes (stick, closed), so the
    iterations converge to the same equilibrium (the residual is exact) and
    slow down only where nodes slip or lift off.
    """
    t0 = time.perf_counter()
    _, K, _ = (loading or NO_LOADING).tangent(model, state.displacement)
    contact = model.diagonal[model.contact_dofs.ravel()]
    K.data[contact] += np.mean(K.data[contact])
    dt = time.perf_counter() - t0
    timings["assembly"] += dt
    timings["tangent"] -= dt  # (the caller times this call as tangent time)
    return Tangent(model, K)


def _flexible(tangent: Tangent) -> bool:
    """The flexibility matrix is finite with a positive diagonal."""
    return bool(tangent.w_mean > 0 and np.all(np.isfinite(tangent.W_scaled)) and np.all(np.diag(tangent.W_scaled) > 0))
