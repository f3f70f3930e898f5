"""Newton equilibrium loop of a load step with the contact correction on the
contact nodes only (paper sect. 8, Box 3 / Box 4).

At Newton iterate ``U_i`` (n_nodes, 3), m, with contact forces ``r_i``
(n_contacts, 3), N, local ``(n, t_x, t_y)``, the linearised problem is
condensed onto the contact dofs with the flexibility matrix
``W = T C K_ff^-1 C^T T^T`` of :mod:`fe_contact.stepping.tangent`:

    u = W r + q,   q = T (w_i + C K_ff^-1 (-R_i)) - W r_i,

where ``w_i`` holds, per contact node, the world tangential displacement increment
over the step and the normal gap, and ``R_i = f_int(U_i) - C^T T^T r_i`` is the
out-of-balance force of the free dofs.  The local solver returns ``r`` satisfying
the De Saxce law (paper eq. 42-45) for this ``u``; the displacement update follows
without refactorising.  Contact kinematics against the plane z = 0 are exactly
linear in ``U``, so at convergence the contact law holds for the true
displacements and the only Newton nonlinearity is geometric.

The loop stops at ``|R_i| <= newton_tol * scale``, the scale being the largest
of the upper-face and contact force norms and the command's own out-of-balance
force (``max(newton_tol, path_tol)`` on a frictional pad's unloading path), or where
rounding stops it (the last correction at rounding level of ``U``); it says "stalled
at r" when the force no longer falls, and gives up at ``newton_max_iter`` (:func:`_verdict`).

With the tangent kept (modified Newton) the iterates are accelerated by
Anderson's mixing (``SolverOptions.acceleration``,
:mod:`fe_contact.stepping.acceleration`): the next iterate may be a combination
of the last plain ones, ``U_i + dU_i``.  A mix's contact forces, the same
combination of local solutions, need not satisfy the law for its displacements
(the weights extrapolate; a mix can leave the cone), so the test is only taken at
a plain iterate: the one after the last correction, whose ``r`` is a local
solution for exactly its displacements (linear kinematics).  The converged
answer thus carries the same certificate, equilibrium to ``newton_tol`` and
the law to ``local_tol``, as without mixing, and differs from that answer by
no more than the tolerances allow (tested: the difference falls with them).
A mix is followed by a plain iterate when the last contraction predicts that
one passes the test; a mix that does not lower the out-of-balance force, or at
which the forces or the contact solve break down, is replaced by the plain
iterate it came from and the differences are forgotten.  A tangent refreshed
at an iterate (nearly Newton's) ends the mixing for the step.

A breakdown (inverted element, non-finite numbers, a tangent that cannot
be factorised, a local solve that does not converge) ends it with a
:class:`~fe_contact.stepping.model.Status`, never an exception.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..fem.elasticity import internal_force
from ..fem.finite_strain import material_limit
from ..fem.loads import NO_LOADING, Loading
from ..contact.local_solver import solve_checked
from .acceleration import Anderson
from .model import IterLog, Model, State, Status
from .tangent import Tangent, refresh_due, refreshed_tangent


@dataclass(frozen=True)
class Equilibrium:
    """Where the Newton loop of a step ended.

    ``displacement`` (n_nodes, 3), m, and ``reaction`` (n_contacts, 3), N,
    local, are the last iterate (the solution when ``status`` is CONVERGED);
    ``internal_force`` (n_dofs,), N, is at that iterate (None if the loop
    stopped before computing one).  ``force_scale`` is the command's
    out-of-balance force, N; ``residual`` the last relative out-of-balance
    force; ``tangent`` the tangent to cache for the next step, or None.
    """

    status: Status
    message: str
    displacement: np.ndarray
    reaction: np.ndarray
    internal_force: np.ndarray | None
    min_det_f: float
    residual: float
    force_scale: float
    iterations: tuple[IterLog, ...]
    tangent_updates: int
    tangent: Tangent | None
    timings: dict


@contextmanager
def _timed(timings: dict, phase: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[phase] += time.perf_counter() - t0


def equilibrium(model: Model, state: State, U: np.ndarray, local_problem_hook=None,
                consume: bool = False, loading: Loading = NO_LOADING, gripper=None,
                guess=None, scale_at: np.ndarray | None = None, path_tol: float | None = None) -> Equilibrium:
    """Newton loop of a step from ``state``, started at ``U`` (n_nodes, 3) with
    the upper face at its commanded pose (``U`` may be updated in place).

    The tangent cached in ``state`` (if of the same free dofs) is reused when
    ``Model.reuses_tangent``, with Anderson's mixing (see the module docstring); with
    ``consume`` it is released at a refresh (see :func:`fe_contact.stepping.step.step`).  ``loading``
    (:class:`~fe_contact.fem.loads.Loading`) makes the out-of-balance force
    ``f_int + f_spring - f_applied - f_contact``.  ``gripper``: a frictional pad's ``(shift, motion)``
    of :meth:`fe_contact.contact.bodies.ContactSet.kinematics`, or a :class:`~fe_contact.stepping.pad_load.LoadDrive`.
    ``guess`` (:class:`~fe_contact.stepping.predictor.StepGuess`, ``U`` its start): its
    contact forces are the first ones (default ``state``'s) and its tangent, if it has
    one, is kept instead of ``state``'s; the step's force scale is the state's either
    way (the same convergence test): taken at ``scale_at`` (n_nodes, 3), m, where
    given (the start without the guess), else at ``U``.  ``path_tol``: a point on a release's
    unloading path, converged at ``max(newton_tol, path_tol)`` and saying so (:func:`_verdict`)."""
    loop = _Loop.start(model, state, loading, consume, local_problem_hook, gripper,
                       None if guess is None else guess.tangent)
    loop.scale_at = scale_at
    r = np.array(state.reaction if guess is None else guess.reaction, dtype=float)
    for it in range(model.options.newton_max_iter + 1):
        mixed = loop.anderson is not None and loop.anderson.mixed  # no convergence test at a mix
        R, f_contact, failure = loop.balance(U, r, it)
        if mixed and (failure is not None or loop.rel_res >= loop.prev_res) and it < model.options.newton_max_iter:
            U, r = loop.anderson.fall_back()  # the mix did no good: back to the plain iterate
            continue
        if failure is None:
            failure = None if mixed else _verdict(model.options, it, loop.rel_res, loop.history, loop.last_step,
                                                 float(np.abs(U).max()), path_tol)
        if failure is not None:
            loop.status, loop.message = failure
            break
        failure = loop.refresh(U, it, mixed)
        if failure is None:
            U, r, failure = loop.correct(U, R, r, f_contact, it, mixed)
        if failure is not None:
            loop.status, loop.message = failure
            break
    return loop.result(U, r)


@dataclass
class _Loop:
    """The state of :func:`equilibrium`'s Newton loop between its stages: the
    tangent and its workspace, Anderson's mixing, the iterates' forces and the
    verdict's history (plain iterates' relative out-of-balance forces, the last
    correction, m)."""

    model: Model
    state: State
    loading: Loading
    consume: bool
    hook: object
    gripper: object
    tangent: Tangent | None
    workspace: object
    anderson: Anderson | None
    timings: dict = field(default_factory=lambda: dict.fromkeys(("assembly", "tangent", "local", "solve"), 0.0))
    logs: list = field(default_factory=list)
    history: list = field(default_factory=list)
    status: Status = Status.NEWTON_NOT_CONVERGED
    message: str = ""
    prev_res: float = math.inf
    rel_res: float = math.inf
    last_step: float = math.inf
    n_tangents: int = 0
    at_start: bool = False
    scale0: float = 0.0
    f_int: np.ndarray | None = None
    min_det: float = math.nan
    K: object = None
    need_tangent: bool = False
    plain: bool = True
    scale_at: np.ndarray | None = None

    @classmethod
    def start(cls, model, state, loading, consume, hook, gripper, tangent=None) -> "_Loop":
        """The loop's start: ``tangent``, else the one cached in ``state``, if it fits (the same free dofs)."""
        tangent = (state.tangent.value if tangent is None else tangent) if model.reuses_tangent else None
        if tangent is not None and tangent.n_free != model.free_dofs.size:
            tangent = None  # cached before the gripper let go: other free dofs
        workspace = tangent.workspace.copy() if tangent is not None else None
        return cls(model, state, loading, consume, hook, gripper, tangent, workspace,
                   _anderson(model, loading, tangent))

    def balance(self, U, r, it: int):
        """Forces at the iterate ``(U, r)``: the out-of-balance force of the free dofs
        ``R`` (sets ``rel_res``), the contact force vector, and a breakdown or None."""
        model = self.model
        self.need_tangent = self.tangent is None or not model.reuses_tangent
        if self.loading.proximal:
            self.loading.anchor[:] = U.ravel()  # the springs damp the correction from here and pull nowhere
        with _timed(self.timings, "assembly"):
            self.f_int, self.K, self.min_det = _forces(model, self.state, U, self.need_tangent, it, self.loading)
        failure = _breakdown(self.f_int, self.min_det, it)
        if failure is not None:
            return None, None, failure
        contact_world, f_contact = _contact_forces(model, r)
        if it == 0:  # with the state's contact forces, whatever the loop starts from
            f_start = _contact_forces(model, self.state.reaction)[1]
            at = U if self.scale_at is None else self.scale_at
            self.scale0 = _command_force_scale(model, self.state, at, f_start, self.loading)
        R, self.rel_res = _out_of_balance(model, self.f_int, f_contact, contact_world, self.scale0)
        return R, f_contact, None

    def refresh(self, U, it: int, mixed: bool):
        """A new tangent at ``U`` when one is needed or due; a failure ``(status, message)`` or None."""
        opts = self.model.options
        self.need_tangent = self.need_tangent or refresh_due(self.tangent, self.at_start, it, self.rel_res,
                                                             self.prev_res, opts, mixed)
        # a plain iterate next if the last contraction says it passes the test
        self.plain = it == 0 or (it >= 2 and self.rel_res**2 <= opts.newton_tol * self.prev_res)
        self.prev_res = self.rel_res
        if not self.need_tangent:
            return None
        # the old factors go before the new ones come (and before the assembly's temporaries: 1.8 GB at 2.3e5 dofs)
        self.tangent = self.workspace = None
        handed, self.K = [self.K], None
        self.tangent, fallback, failure = _new_tangent(self.model, self.state, U, handed, self.consume, it,
                                                       self.timings, self.loading)
        if self.tangent is None:
            return Status.TANGENT_SINGULAR, failure
        self.at_start = self.at_start or fallback
        self.n_tangents += 1
        self.workspace = self.tangent.workspace.copy()
        if self.anderson is not None:
            self.anderson.restart(mixing=it == 0)  # another map; taken at an iterate, nearly Newton's
        return None

    def correct(self, U, R, r, f_contact, it: int, mixed: bool):
        """The contact solve and the next iterate ``(U, r, failure)``."""
        local, dU_free, failure = _contact_correction(self.model, self.state, self.tangent, self.workspace, U, R, r,
                                                      it, self.timings, self.hook, self.gripper)
        if local is not None:
            self.logs.append(IterLog(self.rel_res, int(local.iterations), float(local.residual), local.method, mixed))
        if failure is not None:
            if not mixed or it == self.model.options.newton_max_iter:
                return U, r, failure
            U, r = self.anderson.fall_back()  # the contact solve failed from a mix, not from the plain iterate
            return U, r, None
        self.last_step = float(np.abs(dU_free).max()) if dU_free.size else 0.0
        U, r = _next_iterate(self.model, self.anderson, U, R, f_contact, dU_free, local.r, self.plain)
        return U, r, None

    def result(self, U, r) -> Equilibrium:
        """The :class:`Equilibrium` where the loop ended, a failure's cause named."""
        model = self.model
        status, message = _named_cause(model, self.state, U, self.status, self.message)
        cached = None if not model.reuses_tangent or self.tangent is None else self.tangent.with_workspace(
            self.workspace, None if self.anderson is None else self.anderson.pairs)
        return Equilibrium(status, message, U, r, self.f_int, float(self.min_det), self.rel_res, self.scale0,
                           tuple(self.logs), self.n_tangents, cached, self.timings)


STALL_WINDOW = 8
"""Newton iterations in a row that do not lower the best out-of-balance force by STALL_RATIO: the loop has stalled."""
STALL_RATIO = 0.9
ROUNDING_STEP = 64
"""A correction that moves no dof by more than this many ulps of the iterate (``eps max |U|``) leaves it a fixed
point to rounding: its out-of-balance force is what rounding allows at that load and mesh."""


def _verdict(opts, it: int, rel_res: float, history: list, last_step: float, u_size: float,
             path_tol: float | None = None):
    """The end of the Newton loop at a plain iterate, or None to go on.

    Converged when the relative out-of-balance force is at most ``newton_tol``
    (``max(newton_tol, path_tol)`` on a release's unloading path: "converged to the
    release's path tolerance", with ``r``), or when the last correction was at rounding
    level (``ROUNDING_STEP eps max |U|``, m): no iteration can improve the iterate, its force is what
    rounding allows (a fixed tolerance alone fails converged steps of a fine
    mesh, issue 39).  Stalled (not converged, "stalled at r") when the last
    ``STALL_WINDOW`` iterations did not lower the best force by ``STALL_RATIO``;
    not converged at ``newton_max_iter``.  ``history`` gains ``rel_res``.
    """
    if it == 0:  # the start: the last step's equilibrium under this step's command
        return None
    history.append(rel_res)
    if rel_res <= opts.newton_tol:
        return Status.CONVERGED, ""
    tol, name = (path_tol, "path_tol") if path_tol is not None and path_tol > opts.newton_tol else (opts.newton_tol, "newton_tol")
    if rel_res <= tol:
        return Status.CONVERGED, (f"converged to the release's path tolerance (relative out-of-balance force "
                                  f"{rel_res:.3g} <= path_tol {tol:g}, not newton_tol {opts.newton_tol:g})")
    if last_step <= ROUNDING_STEP * np.finfo(float).eps * u_size:
        return Status.CONVERGED, (f"converged to rounding (relative out-of-balance force {rel_res:.3g}, the last "
                                  f"correction {last_step:.3g} m at rounding level)")
    if len(history) > STALL_WINDOW and min(history[-STALL_WINDOW:]) > STALL_RATIO * min(history[:-STALL_WINDOW]):
        return Status.NEWTON_NOT_CONVERGED, (f"Newton loop stalled at r = {rel_res:.3g} (> {name} "
                                             f"{tol:g}): no fall over {STALL_WINDOW} iterations")
    if it == opts.newton_max_iter:
        return Status.NEWTON_NOT_CONVERGED, (f"Newton loop did not converge in {opts.newton_max_iter} iterations "
                                             f"(relative out-of-balance force {rel_res:.3g} > {name} {tol:g})")
    return None


def _new_tangent(model: Model, state: State, U: np.ndarray, handed: list, consume: bool, it: int, timings: dict,
                 loading: Loading):
    """:func:`~fe_contact.stepping.tangent.refreshed_tangent` from the stiffness in
    ``handed`` (assembled at ``U`` if None there), ``state``'s tangent released
    first with ``consume`` (the caller gave the state up)."""
    if consume:
        state.tangent.release()
    if handed[0] is None:
        with _timed(timings, "assembly"):
            handed[0] = loading.tangent(model, U)[1]
    with _timed(timings, "tangent"):
        return refreshed_tangent(model, state, handed, it, timings, loading)


def _anderson(model: Model, loading: Loading, tangent: Tangent | None) -> Anderson | None:
    """The step's Anderson mixing (:mod:`fe_contact.stepping.acceleration`) with the
    differences ``tangent`` carries, or None: ``SolverOptions.acceleration`` 0, full
    Newton (a map that changes every iteration), or proximal springs (anchored at
    each iterate: likewise)."""
    depth = model.options.acceleration
    if depth == 0 or not model.reuses_tangent or loading.proximal:
        return None
    return Anderson(depth, None if tangent is None else tangent.secants)


def _next_iterate(model: Model, anderson: Anderson | None, U: np.ndarray, R: np.ndarray, f_contact: np.ndarray,
                  dU_free: np.ndarray, r_new: np.ndarray, plain: bool) -> tuple[np.ndarray, np.ndarray]:
    """The plain iterate ``U + dU`` (n_nodes, 3), m, with the contact forces ``r_new``
    (n_contacts, 3), N, of its local solve, or Anderson's mix (``plain`` False).

    ``U`` is updated in place.  ``p(x) = C^T T^T r_new - f(x)`` of the free dofs,
    the force the update corrects, is ``-R`` plus the change of the contact forces."""
    U_flat = U.ravel()
    U_flat[model.free_dofs] += dU_free
    U = U_flat.reshape(-1, 3)
    r = np.array(r_new, dtype=float)
    if anderson is None:
        return U, r
    p = _contact_forces(model, r)[1][model.free_dofs] - f_contact[model.free_dofs] - R
    return anderson.next_iterate(U, r, model.free_dofs, p, plain)


def _named_cause(model: Model, state: State, U: np.ndarray, status: Status, message: str) -> tuple[Status, str]:
    """A failure's cause named when it is the material law's: past its stable
    range at the step's start or its last iterate (StVK in compression)."""
    if status is Status.CONVERGED:
        return status, message
    limit = (material_limit(model.geometry, model.mesh.elements, state.displacement, model.material,
                            "at the start of the step")
             or material_limit(model.geometry, model.mesh.elements, U, model.material, "at the last iterate"))
    if limit is None:
        return status, message
    return Status.MATERIAL_UNSTABLE, f"{limit} ({message})"


def _forces(model: Model, state: State, U: np.ndarray, need_tangent: bool, it: int, loading: Loading):
    """Internal minus applied force (n_dofs,) at ``U``, the stiffness if a
    tangent is to be built (else None), and the smallest ``det F`` at the
    Gauss points."""
    geometry, elements, material = model.geometry, model.mesh.elements, model.material
    K = None
    if need_tangent and model.reuses_tangent and it == 0:
        # A tangent kept for many iterations is best taken at the converged
        # start of the step, an equilibrium state: a tangent at an iterate
        # can be indefinite (see fe_contact.stepping.tangent.refreshed_tangent).
        _, K, _ = loading.tangent(model, state.displacement)
        f_int, min_det = internal_force(geometry, elements, U, material)
    elif need_tangent:
        f_int, K, min_det = loading.tangent(model, U)
    else:
        f_int, min_det = internal_force(geometry, elements, U, material)
    return loading.force(f_int, U), K, min_det


def _breakdown(f_int: np.ndarray, min_det: float, it: int) -> tuple[Status, str] | None:
    """Status and message if the iterate is not a configuration to go on from."""
    if not np.all(np.isfinite(f_int)) or not math.isfinite(min_det):
        return Status.NOT_FINITE, f"non-finite internal force at Newton iteration {it}"
    if min_det <= 0:
        return Status.ELEMENT_INVERTED, f"element inverted (min det F = {min_det:.3g}) at Newton iteration {it}"
    return None


def _contact_forces(model: Model, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World force of each contact node (n_contacts, 3) and as a force vector (n_dofs,)."""
    contact_world = model.contacts.to_world(r)
    f_contact = np.zeros(model.mesh.n_dofs)
    f_contact[model.contact_dofs.ravel()] = contact_world.ravel()
    return contact_world, f_contact


def _out_of_balance(model: Model, f_int, f_contact, contact_world, scale0: float) -> tuple[np.ndarray, float]:
    """Out-of-balance force of the free dofs ``R`` (n_free,), N, and its norm
    relative to the step's force scale."""
    R = (f_int - f_contact)[model.free_dofs]
    scale = max(np.linalg.norm(f_int[model.upper_dofs]), np.linalg.norm(contact_world), scale0)
    rel_res = float(np.linalg.norm(R) / scale) if scale > 0 else float(np.linalg.norm(R))
    return R, rel_res


def _command_force_scale(model: Model, state: State, U: np.ndarray, f_contact: np.ndarray,
                         loading: Loading) -> float:
    """Norm of the out-of-balance force of the step's command applied to the
    upper face alone (the rest of the block left at ``state``), with the
    start's contact forces ``f_contact``.

    A force scale for the step's residual that stays meaningful when the
    block is lifted off and all forces vanish.  The predictor cannot
    give it: a block moved in the plane in the air is in equilibrium to rounding.
    """
    upper = model.held_nodes
    U_upper_only = np.array(state.displacement, dtype=float)
    U_upper_only[upper] = U[upper]
    f_int, _ = internal_force(model.geometry, model.mesh.elements, U_upper_only, model.material)
    f_int = loading.force(f_int, U_upper_only)
    return max(float(np.linalg.norm((f_int - f_contact)[model.free_dofs])), model.weight)


FALLBACK = {"newton": "uzawa", "uzawa": "newton", "uzawa_jacobi": "newton"}
"""The local method a contact solve retries with when the chosen one does not converge."""


def _solve_contact(model: Model, tangent: Tangent, q_scaled: np.ndarray, r: np.ndarray, workspace,
                   tol: float | None = None, method: str | None = None, W: np.ndarray | None = None,
                   retry: bool = True, stall: int | None = None):
    """The local contact problem ``u = W r + q`` of an iteration (scaled, see
    :mod:`fe_contact.stepping.tangent`) solved with ``SolverOptions.local_method``
    warm-started at ``r``; if that does not converge, retried with Newton
    from zero forces with its proximal regularisation (a warm start far from
    the solution can stall it: a frictional pad of mu 60 opening), then with
    :data:`FALLBACK` of the method warm-started (semismooth Newton and the
    paper's Uzawa fail on different problems).  The solution's ``method`` says
    which one solved it; if none did, the one with the smallest residual is
    returned.  ``tol`` and ``method`` replace ``SolverOptions.local_tol`` and
    ``local_method`` (a pad's load equation needs its forces tighter than a
    warm-started Uzawa gives them, :mod:`fe_contact.stepping.pad_load`), ``W``
    the tangent's (a compliant gripper's plate eliminated into it); without
    ``retry`` the first method only, given up after ``stall`` steps without
    progress (:func:`~fe_contact.contact.local_solver.solve_checked`)."""
    opts = model.options
    best = None
    first = method or opts.local_method
    attempts = ((first, r, True), ("newton", np.zeros_like(r), False), (FALLBACK[first], r, True))[:3 if retry else 1]
    for method, start, spd in attempts:
        # the tangent's W was checked when built, q above, r by the last solve
        local = solve_checked(
            tangent.W_scaled if W is None else W, q_scaled, model.contacts.mu_x, model.contacts.mu_y, start, method,
            opts.local_tol if tol is None else tol, opts.local_max_iter,
            assume_spd=spd,  # K_ff is SPD (with the upper face prescribed, or the springs)
            workspace=workspace if method == "newton" and spd else None, stall=None if retry else stall,
        )
        if local.converged:
            return local
        best = local if best is None or local.residual < best.residual else best
    return best


def _contact_correction(model: Model, state: State, tangent: Tangent, workspace, U, R, r, it: int,
                        timings: dict, local_problem_hook, gripper=None):
    """Contact solve and displacement update of one Newton iteration.

    Returns the :class:`~fe_contact.contact.local_solver.LocalSolution` (None if not
    solved), the update of the free dofs (n_free,), m, and None, or a failure
    ``(status, message)`` instead of the update.
    """
    contacts, nodes, opts = model.contacts, model.contacts.nodes, model.options
    with _timed(timings, "solve"):
        dw0, finish_solve = tangent.solve_with_contact(-R)
        drive = None if gripper is None or isinstance(gripper, tuple) else gripper
        shift, motion = (np.zeros(3), 0.0) if gripper is None else gripper if drive is None else drive.kinematics()
        gap, slip = contacts.kinematics(model.mesh.nodes[nodes] + U[nodes], U[nodes] - state.displacement[nodes],
                                        motion, shift)
        w = contacts.to_local(slip + dw0)
        w[:, 0] = gap + np.einsum("ci,ci->c", contacts.frames[:, 0, :], dw0)  # normal gap, not its increment
        q_scaled = w / tangent.w_mean - (tangent.W_scaled @ r.ravel()).reshape(-1, 3)
    if not np.all(np.isfinite(q_scaled)):
        return None, None, (Status.NOT_FINITE, f"non-finite contact problem at Newton iteration {it}: "
                                               "the solve with the tangent broke down")
    with _timed(timings, "local"):
        if drive is None:
            local = _solve_contact(model, tangent, q_scaled, r, workspace)
        else:  # the pad's height with its load equation (fe_contact.stepping.pad_load)
            def load_solve(q, start, W=None, full=True, stall=None):  # tight by semismooth Newton, else as any step's
                local = _solve_contact(model, tangent, q, start, workspace, drive.local_tol, "newton", W, False, stall)
                return local if local.converged or not full else _solve_contact(model, tangent, q, start, workspace,
                                                                                W=W)

            local, q_scaled, W_scaled = drive.solve(load_solve, q_scaled, r, tangent.w_mean, tangent.W_scaled)
    if local_problem_hook is not None:
        local_problem_hook(tangent.W_scaled if drive is None else W_scaled, q_scaled, local)
    if drive is not None and drive.failure:
        return local, None, (Status.CONTACT_NOT_CONVERGED, f"{drive.failure} at Newton iteration {it}")
    if not local.converged:
        return local, None, (Status.CONTACT_NOT_CONVERGED,
                             f"contact did not converge at Newton iteration {it} with {opts.local_method}, "
                             f"newton from zero nor {FALLBACK[opts.local_method]}: residual {local.residual:.3g} after "
                             f"{local.iterations} iterations")
    with _timed(timings, "solve"):
        dU_free = finish_solve(contacts.to_world(local.r - r))
    if not np.all(np.isfinite(dU_free)):
        return local, None, (Status.NOT_FINITE, f"non-finite displacement update at Newton iteration {it}")
    return local, dU_free, None
