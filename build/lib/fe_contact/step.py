"""One quasi-static load step: Newton equilibrium loop with the contact correction
on the contact nodes only (paper sect. 8, Box 3 / Box 4).

At Newton iterate ``U_i`` with contact forces ``r_i`` the linearised problem is
condensed onto the contact dofs with the flexibility matrix
``W = T C K_ff^-1 C^T T^T`` (contact block of the inverse tangent, local frames):

    u = W r + q,   q = T (w_i + C K_ff^-1 (-R_i)) - W r_i,

where ``w_i`` holds, per contact node, the world tangential displacement increment
over the step and the normal gap, and ``R_i = f_int(U_i) - C^T T^T r_i`` is the
out-of-balance force of the free dofs.  The local solver returns ``r`` satisfying
the De Saxce law (paper eq. 42-45) for this ``u``; the displacement update follows
without refactorising.  Contact kinematics against the plane z = 0 are exactly
linear in ``U``, so at convergence the contact law holds for the true
displacements and the only Newton nonlinearity is geometric.
"""

from __future__ import annotations

import copy
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse.linalg as spla

from ._threads import dense_kernel, dense_threads
from .cholesky import NotPositiveDefinite, SupernodalFactor, factorise
from .elasticity import internal_force, internal_force_and_tangent
from .local_solver import NewtonWorkspace, solve_local
from .model import Command, IterLog, Model, NodeStatus, State, Status, StepReport
from .pose import face_centroid_displacement, planar_yaw, twist_angle

_THREADED_WORK = 2_000_000  # right-hand sides x free dofs above which W is computed on threads
_RHS_BLOCK_ENTRIES = 25_000_000  # right-hand sides x free dofs solved at once for W on SuperLU (200 MB)
SEPARATION_FORCE = 1e-9
"""Normal force, relative to the largest contact force component, at or below which a node counts as separated."""
SLIP_DISPLACEMENT = 1e-9
"""Tangential increment, relative to the largest block dimension, above which a contact node counts as slipping."""


def upper_face_displacement(model: Model, translation: np.ndarray, rotation: float) -> np.ndarray:
    """Displacement of the upper-face nodes for a rigid pose of the upper face.

    Parameters
    ----------
    translation : ndarray, shape (3,)
        Cumulative translation of the upper face, m.
    rotation : float
        Cumulative rotation about the vertical axis through the (translated)
        upper-face centre, rad.

    Returns
    -------
    ndarray, shape (n_upper, 3)
    """
    X = model.mesh.nodes[model.mesh.upper]
    c = model.upper_centre
    cs, sn = math.cos(rotation), math.sin(rotation)
    rel = X - c
    x = np.empty_like(X)
    x[:, 0] = c[0] + cs * rel[:, 0] - sn * rel[:, 1]
    x[:, 1] = c[1] + sn * rel[:, 0] + cs * rel[:, 1]
    x[:, 2] = X[:, 2]
    return x + translation - X


def predictor(model: Model, state: State, command: Command) -> np.ndarray:
    """Start of a step's Newton loop, as displacements (n_nodes, 3): the
    configuration of ``state`` carried by the in-plane rigid part of
    ``command`` (``dx``, ``dy`` and ``dtheta`` about the current centre of the
    upper face), with ``dz`` spread linearly over the height (a homogeneous
    compression or stretch; the lower face keeps its height).

    The caller then puts the upper face at its commanded pose.  Moving the
    upper face alone would strain the top layer by the whole increment: a
    press of 1 % of the height squeezes the top element layer of a 5-layer
    mesh by 5 %, and a push shears it by the whole push and leaves the lower
    face behind.  A sliding block moves nearly rigidly and a pressed one
    nearly homogeneously, so this start is much closer to the solution: on
    the paper's case 3 the press takes 6 Newton iterations instead of 8 and
    the pushes 4-8 instead of 9; a push of 4 mm or a turn of 30 deg in one
    step converges where the upper-face-only start inverted elements.  The
    solution is the same.
    """
    x = model.mesh.nodes + state.displacement
    centre = model.upper_centre[:2] + state.upper_translation[:2]
    cs, sn = math.cos(command.dtheta), math.sin(command.dtheta)
    rel = x[:, :2] - centre
    U = np.array(state.displacement, dtype=float)
    U[:, 0] += cs * rel[:, 0] - sn * rel[:, 1] - rel[:, 0] + command.dx
    U[:, 1] += sn * rel[:, 0] + cs * rel[:, 1] - rel[:, 1] + command.dy
    Z = model.mesh.nodes[:, 2]
    U[:, 2] += command.dz * (Z - Z.min()) / (Z.max() - Z.min())
    return U


def _command_force_scale(model: Model, state: State, U: np.ndarray, f_contact: np.ndarray) -> float:
    """Norm of the out-of-balance force of the step's command applied to the
    upper face alone (the rest of the block left at ``state``), with the
    start's contact forces ``f_contact``.

    A force scale for the step's residual that stays meaningful when the
    block is lifted off and all forces vanish.  The predictor cannot
    give it: a block moved in the plane in the air is in equilibrium to rounding.
    """
    upper = model.mesh.upper
    U_upper_only = np.array(state.displacement, dtype=float)
    U_upper_only[upper] = U[upper]
    f_int, _ = internal_force(model.geometry, model.mesh.elements, U_upper_only, model.material)
    return float(np.linalg.norm((f_int - f_contact)[model.free_dofs]))


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


class _LUFactor:
    """SuperLU factors of ``K_ff`` with the solve interface of
    :class:`~fe_contact.cholesky.SupernodalFactor` (for an indefinite tangent
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


def _refresh_pays(tangent: "_Tangent", rate: float, rel_res: float, opts, it: int) -> bool:
    """Whether a new tangent saves more iterations than it costs.

    At contraction ``rate`` per iteration, reaching ``newton_tol`` from
    ``rel_res`` takes ``log(tol / res) / log(rate)`` iterations, with a fresh
    tangent about ``log(tol / res) / log(_FRESH_RATE)``.  A tangent that does
    not contract, or would not converge within ``newton_max_iter``, is always
    refreshed.
    """
    if rate >= 1.0:
        return True
    gap = math.log(opts.newton_tol / rel_res)
    needed = gap / math.log(rate)
    if it + needed > opts.newton_max_iter:
        return True
    saved = needed - gap / math.log(_FRESH_RATE)
    return saved * tangent.iteration_s > tangent.build_s


class _Tangent:
    """Factorised free-dof tangent and the flexibility matrix derived from it.

    ``W`` is the contact block of ``K_ff^-1``.  On a tensor-grid mesh the
    tangent is factorised by the multifrontal Cholesky of
    :mod:`fe_contact.cholesky`, which eliminates the contact dofs last, so
    ``W`` is the inverse of the Schur complement it leaves (no solves with
    one right-hand side per contact dof).  If the tangent is not positive
    definite, or the mesh is not a grid, SuperLU factorises it and ``K_ff^-1``
    is applied to one unit vector per contact dof, on
    :func:`~fe_contact._threads.dense_threads` threads (SuperLU releases the GIL).
    With ``lu_fallback=False`` a grid mesh's tangent that is not positive
    definite raises :class:`~fe_contact.cholesky.NotPositiveDefinite` instead.
    """

    def __init__(self, model: Model, K, lu_fallback: bool = True):
        free = model.free_dofs
        n_lower = model.n_contacts
        # Positions of the contact dofs (x, y, z per node) inside the free-dof vector.
        self.contact_index = np.searchsorted(free, model.lower_dofs.ravel())
        self.n_free = free.size
        m = 3 * n_lower
        structure = model.factor_structure
        n_points = model.geometry.dvol.size
        G = None
        if structure is not None:
            try:
                with dense_kernel(structure.max_front):
                    self.factor = factorise(structure, K.data)
                    G = self.factor.root_inverse()  # contact dofs in lower_dofs order
                self.method = "multifrontal"
                build_s = (structure.flops + m**3) / _DENSE_FLOPS
            except NotPositiveDefinite:
                if not lu_fallback:
                    raise
                G = None
        if G is None:
            self.factor = _LUFactor(K, free, None if structure is None else structure.perm)
            self.method = "superlu"
            G = self._sparse_compliance(n_lower)
            G = 0.5 * (G + G.T)  # exact symmetry
            build_s = _FACTOR_SOLVES * 2.0 * self.factor.nnz / _SPARSE_FLOPS + m * 2.0 * self.factor.nnz / _SPARSE_W_FLOPS
        # estimated seconds (see _refresh_pays)
        solve_s = 4.0 * self.factor.nnz / _SPARSE_FLOPS
        local_s = _LOCAL_PRODUCTS * 2.0 * float(m) ** 2 / _SPARSE_FLOPS
        self.build_s = n_points * _S_PER_TANGENT_POINT + build_s
        solves = 1.0 if self.method == "multifrontal" else 2.0  # per iteration (solve_with_contact)
        self.iteration_s = _ITERATION_OVERHEAD_S + n_points * _S_PER_GAUSS_POINT + solves * solve_s + local_s
        # to the local frames, W = (I x T) G (I x T)^T, in place a band of rows at
        # a time (two batched products; no second matrix of W's size)
        T = model.frame
        W = G
        blocks = W.reshape(n_lower, 3, n_lower, 3)
        for i in range(0, n_lower, 256):
            band = blocks[i:i + 256]
            band[...] = (T @ band.reshape(-1, 3, m)).reshape(band.shape) @ T.T
        # Divided by its mean diagonal compliance, u = W r + q has force units, so
        # the natural-map residual (r - proj(r - modified(u))) is homogeneous; the
        # contact law is invariant under this scaling of u.  Kept scaled, once.
        self.w_mean = float(np.mean(np.diag(W)))
        W /= self.w_mean
        self.W_scaled = W
        # the local Newton matrix factorised in one iteration serves the next ones;
        # a step works on a copy, so that stepping twice from one state agrees
        self.workspace = NewtonWorkspace()

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

    def with_workspace(self, workspace: NewtonWorkspace) -> "_Tangent":
        other = copy.copy(self)
        other.workspace = workspace
        return other

    def solve(self, rhs_free: np.ndarray) -> np.ndarray:
        """``K_ff^-1 rhs`` for one right-hand side (n_free,) or several (n_free, k)."""
        return self.factor.solve(rhs_free)

    def solve_with_contact(self, rhs_free: np.ndarray):
        """Begin ``K_ff^-1 (rhs + C^T f)`` for contact-node forces ``f`` not
        known yet.

        Returns the contact-node displacements of ``K_ff^-1 rhs`` (n_lower, 3)
        and a function of ``f`` (n_lower, 3, world frame) that returns the
        whole solution (n_free,).  On the multifrontal factor this is one
        forward and one backward substitution in all: the contact dofs are
        eliminated last, so ``f`` changes only the root block of the forward
        pass.  On SuperLU it is two solves.
        """
        if isinstance(self.factor, SupernodalFactor):
            factor = self.factor
            y = factor.forward(rhs_free)
            contact = factor.root_backward(y).reshape(-1, 3)

            def finish(force_world):
                y[-3 * contact.shape[0]:, 0] += factor.root_forward(force_world.ravel())
                return factor.backward(y).ravel()

            return contact, finish
        x = self.solve(rhs_free)

        def finish_lu(force_world):
            rhs = np.zeros(self.n_free)
            rhs[self.contact_index] = force_world.ravel()
            return x + self.solve(rhs)

        return x[self.contact_index].reshape(-1, 3), finish_lu


def step(model: Model, state: State, command: Command, local_problem_hook=None, *,
         consume: bool = False) -> tuple[State, StepReport]:
    """Apply one load step.

    Parameters
    ----------
    model : Model
    state : State
        State at the start of the step (not modified).
    command : Command
        Rigid motion increment of the upper face.
    local_problem_hook : callable, optional
        Called as ``hook(W, q, solution)`` after every local contact solve with
        the problem exactly as the local solver got it: ``u = W r + q`` in the
        local frames, divided by the mean diagonal compliance so that ``W`` is
        dimensionless and ``q``, ``u`` are in N like ``r``; ``solution`` is the
        :class:`~fe_contact.local_solver.LocalSolution`.  For exporting the
        problems (FCLIB) or studying solvers; the hook must not modify them.
    consume : bool
        The caller will not step from ``state`` again (a run that only goes
        forward): when the step refreshes the tangent, ``state``'s cached one is
        dropped first, so that one factorised tangent is alive instead of two
        (at 2e5 dofs a tangent is about 4.5 GB).  The results are the same;
        ``state`` merely loses its cache.  Leave False to branch from ``state``.

    Returns
    -------
    new_state : State
        State at the end of the step; the input ``state`` when the step failed.
    report : StepReport
        Measurements of the step; ``report.status`` tells whether it converged and
        which loop failed otherwise.
    """
    if not isinstance(model, Model):
        raise ValueError(f"model must be a Model, got {type(model).__name__}")
    if not isinstance(state, State):
        raise ValueError(f"state must be a State, got {type(state).__name__}")
    if not isinstance(command, Command):
        raise ValueError(f"command must be a Command, got {type(command).__name__}")
    if state.displacement.shape != (model.mesh.n_nodes, 3):
        raise ValueError(
            f"state.displacement has shape {state.displacement.shape}, model needs {(model.mesh.n_nodes, 3)}"
        )
    t0 = time.perf_counter()
    opts = model.options
    mesh = model.mesh
    T = model.frame
    mu_x, mu_y = model.friction.mu_x, model.friction.mu_y
    free = model.free_dofs
    lower = mesh.lower

    translation = state.upper_translation + np.array([command.dx, command.dy, command.dz])
    rotation = state.upper_rotation + command.dtheta
    U = predictor(model, state, command)
    U[mesh.upper] = upper_face_displacement(model, translation, rotation)
    U_start_lower = state.displacement[lower]
    r = np.array(state.reaction, dtype=float)

    status, message = Status.NEWTON_NOT_CONVERGED, ""
    logs: list[IterLog] = []
    tangent = state.tangent if opts.reuse_tangent else None
    workspace = tangent.workspace.copy() if tangent is not None else None
    prev_res = math.inf
    n_tangents = 0
    at_start = False  # the tangent in use was taken at the start state as a fallback
    timings = dict.fromkeys(("assembly", "tangent", "local", "solve"), 0.0)
    rel_res = math.inf
    min_det = math.nan
    f_int = None
    scale0 = 0.0
    for it in range(opts.newton_max_iter + 1):
        need_tangent = tangent is None or not opts.reuse_tangent
        t_phase = time.perf_counter()
        if need_tangent and opts.reuse_tangent and it == 0:
            # A tangent kept for many iterations is best taken at the converged
            # start of the step, an equilibrium state: a tangent at an iterate
            # can be indefinite (see the fallback below).
            _, K, _ = internal_force_and_tangent(
                model.geometry, mesh.elements, state.displacement, model.material, model.pattern
            )
            f_int, min_det = internal_force(model.geometry, mesh.elements, U, model.material)
        elif need_tangent:
            f_int, K, min_det = internal_force_and_tangent(
                model.geometry, mesh.elements, U, model.material, model.pattern
            )
        else:
            f_int, min_det = internal_force(model.geometry, mesh.elements, U, model.material)
        timings["assembly"] += time.perf_counter() - t_phase
        if not np.all(np.isfinite(f_int)) or not math.isfinite(min_det):
            status, message = Status.NOT_FINITE, f"non-finite internal force at Newton iteration {it}"
            break
        if min_det <= 0:
            status, message = (
                Status.ELEMENT_INVERTED,
                f"element inverted (min det F = {min_det:.3g}) at Newton iteration {it}",
            )
            break
        contact_world = r @ T  # (n_lower, 3) world force of each contact node
        f_contact = np.zeros(mesh.n_dofs)
        f_contact[model.lower_dofs.ravel()] = contact_world.ravel()
        R = (f_int - f_contact)[free]
        if it == 0:
            scale0 = _command_force_scale(model, state, U, f_contact)
        scale = max(np.linalg.norm(f_int[model.upper_dofs]), np.linalg.norm(contact_world), scale0)
        rel_res = float(np.linalg.norm(R) / scale) if scale > 0 else float(np.linalg.norm(R))
        if it > 0 and rel_res <= opts.newton_tol:
            status = Status.CONVERGED
            break
        if it == opts.newton_max_iter:
            message = (
                f"Newton loop did not converge in {opts.newton_max_iter} iterations "
                f"(relative out-of-balance force {rel_res:.3g} > {opts.newton_tol:g})"
            )
            break
        # (the first correction of a step also settles the contact statuses, so
        # its contraction says little about the tangent)
        if (not need_tangent and not at_start and it >= 2 and rel_res > opts.refresh_ratio * prev_res
                and _refresh_pays(tangent, rel_res / prev_res, rel_res, opts, it)):
            # the reused tangent contracts too slowly here: refresh it (not
            # after a fallback: another would come back to the same tangent)
            need_tangent = True
            K = None
        prev_res = rel_res
        if need_tangent:
            # the old factors go before the new ones come (and before the
            # assembly's temporaries: 1.8 GB at 2.3e5 dofs)
            tangent = workspace = W_scaled = None
            if consume:
                object.__setattr__(state, "tangent", None)  # a cache; the caller gave the state up
            if K is None:
                t_phase = time.perf_counter()
                _, K, _ = internal_force_and_tangent(model.geometry, mesh.elements, U, model.material, model.pattern)
                timings["assembly"] += time.perf_counter() - t_phase
        t_phase = time.perf_counter()
        if need_tangent:
            try:
                try:
                    # a tangent at an iterate (K is at the start state only at
                    # iteration 0 with reuse) may be indefinite: an iterate can
                    # strain the top layer past St Venant-Kirchhoff's stable
                    # range in compression (E = -0.49, det F = 0.2 at 2.3e5 dofs)
                    tangent = _Tangent(model, K, lu_fallback=it == 0 and opts.reuse_tangent)
                except NotPositiveDefinite:
                    # take it at the converged start of the step instead, as
                    # a step without a cached tangent does
                    t_assembly = time.perf_counter()
                    K = None
                    _, K, _ = internal_force_and_tangent(
                        model.geometry, mesh.elements, state.displacement, model.material, model.pattern
                    )
                    t_assembly = time.perf_counter() - t_assembly
                    timings["assembly"] += t_assembly
                    t_phase += t_assembly  # (not tangent time too)
                    tangent = _Tangent(model, K)
                    at_start = True
            except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
                status, message = Status.TANGENT_SINGULAR, f"tangent stiffness singular at Newton iteration {it}: {exc}"
                break
            n_tangents += 1
            workspace = tangent.workspace.copy()
            w_diag = np.diag(tangent.W_scaled)
            if not (tangent.w_mean > 0 and np.all(np.isfinite(tangent.W_scaled)) and np.all(w_diag > 0)):
                # a flexibility matrix must be positive definite; rounding has won
                # (e.g. nearly incompressible material, nu -> 0.5)
                status, message = (
                    Status.TANGENT_SINGULAR,
                    f"flexibility matrix not positive definite at Newton iteration {it} "
                    f"(min scaled diagonal {w_diag.min():.3g}): tangent stiffness too ill-conditioned",
                )
                break
        timings["tangent"] += time.perf_counter() - t_phase
        t_phase = time.perf_counter()
        dw0, finish_solve = tangent.solve_with_contact(-R)
        w = U[lower] - U_start_lower
        w[:, 2] = mesh.nodes[lower, 2] + U[lower, 2]  # normal gap, not its increment
        W_scaled = tangent.W_scaled
        q_scaled = (w + dw0) @ T.T / tangent.w_mean - (W_scaled @ r.ravel()).reshape(-1, 3)
        timings["solve"] += time.perf_counter() - t_phase
        t_phase = time.perf_counter()
        local = solve_local(
            W_scaled, q_scaled, mu_x, mu_y,
            method=opts.local_method, tol=opts.local_tol, max_iter=opts.local_max_iter, r0=r,
            assume_spd=True,  # K_ff is SPD with the upper face prescribed
            workspace=workspace,
        )
        timings["local"] += time.perf_counter() - t_phase
        if local_problem_hook is not None:
            local_problem_hook(W_scaled, q_scaled, local)
        logs.append(IterLog(rel_res, int(local.iterations), float(local.residual)))
        if not local.converged:
            status = Status.CONTACT_NOT_CONVERGED
            message = (
                f"contact ({opts.local_method}) did not converge at Newton iteration {it}: "
                f"residual {local.residual:.3g} after {local.iterations} iterations"
            )
            break
        t_phase = time.perf_counter()
        dU_free = finish_solve((local.r - r) @ T)
        timings["solve"] += time.perf_counter() - t_phase
        U_flat = U.ravel()
        U_flat[free] += dU_free
        U = U_flat.reshape(-1, 3)
        r = np.array(local.r, dtype=float)
    contact_residual = logs[-1].contact_residual if logs else 0.0

    # ---- measurements ------------------------------------------------------
    contact_world = r @ T
    slip_inc = U[lower, :2] - U_start_lower[:, :2]
    du_local = slip_inc @ T[1:, :2].T  # (n_lower, 2) in (t_x, t_y)
    gap = mesh.nodes[lower, 2] + U[lower, 2]
    r_scale = float(np.abs(r).max()) if r.size else 0.0
    separated = r[:, 0] <= SEPARATION_FORCE * r_scale
    slipping = ~separated & (
        np.linalg.norm(slip_inc, axis=1) > SLIP_DISPLACEMENT * max(mesh.size)
    )
    node_status = np.where(separated, NodeStatus.SEPARATED, np.where(slipping, NodeStatus.SLIP, NodeStatus.STICK))
    slip_path = state.slip_path + np.linalg.norm(slip_inc, axis=1)
    upper_c = face_centroid_displacement(U[mesh.upper], model.upper_area)
    lower_c = face_centroid_displacement(U[lower], model.lower_area)
    X_lower = mesh.nodes[lower]
    tw = twist_angle(upper_c, lower_c, max(mesh.size))
    upper_force = f_int[model.upper_dofs].reshape(-1, 3).sum(axis=0) if f_int is not None else np.zeros(3)
    total_contact = contact_world.sum(axis=0)
    force_scale = max(np.linalg.norm(upper_force), np.linalg.norm(total_contact), scale0)
    eq_err = float(np.linalg.norm(total_contact + upper_force) / force_scale) if force_scale > 0 else 0.0
    report = StepReport(
        status=status,
        message=message or "converged",
        step_index=state.step_index + 1,
        command=command,
        displacement=U,
        reaction_local=r,
        reaction_world=contact_world,
        pressure=r[:, 0] / model.lower_area,
        slip_increment=slip_inc,
        slip=np.linalg.norm(U[lower, :2], axis=1),
        slip_path=slip_path,
        gap=gap,
        node_status=node_status.astype(np.int8),
        upper_centroid=upper_c,
        lower_centroid=lower_c,
        lower_yaw=planar_yaw(X_lower, X_lower + U[lower], model.lower_area),
        twist=tw,
        lag=upper_c[:2] - lower_c[:2],
        normal_force=float(r[:, 0].sum()),
        tangential_force=total_contact[:2],
        upper_force=upper_force,
        equilibrium_error=eq_err,
        dissipation=float(-(r[:, 1:] * du_local).sum()),
        newton_iterations=len(logs),
        contact_iterations=sum(log.contact_iterations for log in logs),
        newton_residual=rel_res,
        contact_residual=contact_residual,
        min_det_f=float(min_det),
        wall_time=time.perf_counter() - t0,
        iterations=tuple(logs),
        tangent_updates=n_tangents,
        timings=timings,
    )
    if status is not Status.CONVERGED:
        return state, report
    new_state = State(
        displacement=U,
        reaction=r,
        upper_translation=translation,
        upper_rotation=rotation,
        slip_path=slip_path,
        step_index=state.step_index + 1,
        tangent=tangent.with_workspace(workspace) if opts.reuse_tangent and tangent is not None else None,
    )
    return new_state, report


def run(model: Model, commands, state: State | None = None, stop_on_failure: bool = True):
    """Apply a sequence of commands.

    Returns
    -------
    state : State
        Final state (the last good one if a step failed and ``stop_on_failure``).
    reports : list[StepReport]
    """
    from .model import initial_state

    state = initial_state(model) if state is None else state
    reports = []
    for i, cmd in enumerate(commands):
        # the states in between are run's own: their tangents may go at a refresh
        state, rep = step(model, state, cmd, consume=i > 0)
        reports.append(rep)
        if not rep.converged and stop_on_failure:
            break
    return state, reports
