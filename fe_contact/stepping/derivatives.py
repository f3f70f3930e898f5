"""Exact derivatives of a rollout: forward (tangent) propagation of the
held-step sensitivities of :mod:`fe_contact.stepping.sensitivity` through a
sequence of steps, and their check against central differences.

Inputs (columns): the components ``(dx, dy, dz, dtheta)`` of every command
(m, rad) and the parameters :data:`PARAMETERS` (``mu_x``, ``mu_y`` -,
``angle`` rad, ``young`` Pa, ``poisson`` -, ``density`` kg/m^3,
``stiffness_xy`` N/m, ``stiffness_yaw`` N m/rad).  Outputs (rows) after every
step: :data:`OUTPUTS`, the lower face's pose ``(x, y, yaw)`` (centroid
displacement, m, best-fit yaw, rad), the force the upper-face drive applies
(N, world) and the plate's in-plane pose (m, rad; the commanded one for a
rigid drive).  A step depends on the previous one through its start
displacements (the slip increment of the friction law), so the state
derivative ``dU/d(input)`` (n_dofs, J) is carried from step to step, each
step costing one tangent factorisation at the converged configuration (handed
on as the next step's cached tangent, so a plain step would have built it
too) and two back-substitutions per input.

The compliant gripper (:mod:`fe_contact.stepping.gripper`) solves the plate
balance ``g(p) = F(p) - k (c - p) = 0``; differentiating it,

    (dF/dp + diag k) dp = k dc + (c - p) dk - dF/d(input)|_p,

with ``dF/dp`` from three more directions of the same held step.

A bonded lift (``release=Release("lift", n)``) adds one row, the rest after
the release.  Its steps are held steps whose heights the release schedule
chose (:class:`~fe_contact.stepping.release.ReleaseSchedule`): each height is
differentiated as the schedule computed it (a lift step ``h + d / n``, ``d``
the press depth; a put-down target of
:func:`~fe_contact.stepping.release_path.put_down_target`, a function of the
heights and forces met, of the weight and of ``E A / H``), and the last one,
the put-down's root ``h*`` where the plate carries nothing, by the implicit
function theorem on ``g(h*, p) = F_z = 0``: ``dh*/dp = -g_p / g_h``, ``g_h``
from one more input column (the step's own height).  The path matters: the
put-down overshoots below ``h*`` and comes back, and the contacts that slip
on the way keep it.  A frictional pad's release
(:mod:`~fe_contact.stepping.pad_sensitivity` for its steps) is
differentiated the same way, each load step's height as the root of its
load (:func:`~fe_contact.stepping.release_derivatives.load_step_root`).  Open releases (``open > 0``) and a
release with a retreat are not differentiated.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..fem.loads import Gripper
from .model import Command, Friction, Model, State, Status, StepReport, TangentCache, initial_state
from .release import Release
from .step import half_command, step
from .release_derivatives import RecordingSequence, load_step_root, put_down_root, release_height_derivative
from .predictor import commanded_pose
from .sequence import StepSequence
from .pad_sensitivity import PadLinearisation
from .sensitivity import (HeldLinearisation, lower_pose_derivative, plate_wrench_derivative, upper_pose_jacobian)

COMPONENTS = ("dx", "dy", "dz", "dtheta")
PARAMETERS = ("mu_x", "mu_y", "angle", "young", "poisson", "density", "stiffness_xy", "stiffness_yaw")
OUTPUTS = ("lower_x", "lower_y", "lower_yaw", "force_x", "force_y", "force_z", "plate_x", "plate_y", "plate_yaw")


@dataclass(frozen=True)
class RolloutDerivatives:
    """A rollout's outputs and their exact derivatives.

    Attributes
    ----------
    status : Status
        CONVERGED, or the status of the step that failed (then the arrays
        hold the steps before it).
    message : str
    outputs : ndarray, shape (n_steps, 9)
        :data:`OUTPUTS` after each step (SI, rad).
    d_commands : ndarray, shape (n_steps, 9, n_steps, 4)
        ``d outputs[k, i] / d commands[j, c]`` (zero for ``j > k``).
    d_parameters : ndarray, shape (n_steps, 9, n_parameters)
        Derivatives with respect to ``parameters``.
    parameters : tuple of str
    state : State
        Final state.
    reports : tuple of StepReport
    wall_time : float
        s.
    parameter_state : StateDerivative
        Derivatives of the final state with respect to ``parameters`` (to
        continue the rollout: ``rollout_derivatives(..., start=this)``).
    """

    status: Status
    message: str
    outputs: np.ndarray
    d_commands: np.ndarray
    d_parameters: np.ndarray
    parameters: tuple
    state: State
    reports: tuple
    wall_time: float
    parameter_state: "StateDerivative"

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    def jacobian(self) -> np.ndarray:
        """All derivatives as one matrix (n_steps * 9, n_steps * 4 + n_parameters),
        rows step-major, columns the commands step-major then the parameters."""
        K = self.outputs.shape[0]
        return np.hstack([self.d_commands.reshape(K * 9, -1), self.d_parameters.reshape(K * 9, -1)])


def applicable_parameters(model: Model) -> tuple[str, ...]:
    """The parameters with a two-sided derivative: the gripper's stiffnesses only
    for a compliant gripper, the density only if > 0."""
    out = list(PARAMETERS[:5])
    if model.material.density > 0:
        out.append("density")
    if not model.gripper.rigid:
        out += ["stiffness_xy", "stiffness_yaw"]
    return tuple(out)


def parameter_values(model: Model) -> dict:
    """The model's values of :data:`PARAMETERS` (SI, rad)."""
    f, m, g = model.friction, model.material, model.gripper
    return {"mu_x": f.mu_x, "mu_y": f.mu_y, "angle": f.angle, "young": m.young, "poisson": m.poisson,
            "density": m.density, "stiffness_xy": g.stiffness_xy, "stiffness_yaw": g.stiffness_yaw}


def with_parameters(model: Model, **values) -> Model:
    """``model`` with some :data:`PARAMETERS` changed (a new Model, same mesh and options)."""
    unknown = set(values) - set(PARAMETERS)
    if unknown:
        raise ValueError(f"unknown parameter {sorted(unknown)[0]!r}; choose from {PARAMETERS}")
    v = {**parameter_values(model), **values}
    return replace(model, friction=Friction(v["mu_x"], v["mu_y"], v["angle"]),
                   material=replace(model.material, young=v["young"], poisson=v["poisson"], density=v["density"]),
                   gripper=Gripper(v["stiffness_xy"], v["stiffness_yaw"]))


def _check(model, commands, parameters, release=None) -> tuple[list, tuple]:
    if not isinstance(model, Model):
        raise ValueError(f"model must be a Model, got {type(model).__name__}")
    if release is not None and (not isinstance(release, Release) or release.mode != "lift"
                                or any(getattr(release, "away", (0.0, 0.0)))):
        raise ValueError(f"release must be a Release of mode 'lift' straight up (an open release, or a retreat "
                         f"away, is not differentiated), got {release!r}")
    if model.pad is not None and not model.gripper.rigid:
        raise ValueError("a compliant gripper with a frictional pad is not differentiated (its plate's pose, solved "
                         "in the step's Newton loop, has no derivative here yet): use a rigid gripper")
    commands = list(commands)
    for k, c in enumerate(commands):
        if not isinstance(c, Command):
            raise ValueError(f"commands[{k}] must be a Command, got {type(c).__name__}")
    parameters = applicable_parameters(model) if parameters is None else tuple(parameters)
    for p in parameters:
        if p not in PARAMETERS:
            raise ValueError(f"unknown parameter {p!r}; choose from {PARAMETERS}")
        if p.startswith("stiffness") and model.gripper.rigid:
            raise ValueError(f"{p} has no derivative with a rigid gripper (stiffness inf)")
    return commands, parameters


def _differentiated(release: Release | None) -> Release | None:
    """The release differentiated: a pad's load steps by backward Euler (the midpoint's are not, yet)."""
    return None if release is None else replace(release, scheme="backward_euler")


def rollout_derivatives(model: Model, commands, state: State | None = None, parameters=None,
                        start: RolloutDerivatives | None = None, release: Release | None = None) -> RolloutDerivatives:
    """Run ``commands`` from ``state`` (default: the undeformed block) and
    differentiate every output of every step (module docstring).

    ``state`` is held fixed: its own dependence on the parameters is not
    included.  To include it, give instead ``start``, an earlier converged
    result of this model (e.g. the press), whose final state and parameters
    the rollout continues from.  With ``release`` (a ``"lift"`` straight up, of
    the bonded or a frictional pad), the block is let go after the commands
    (:class:`~fe_contact.stepping.release.ReleaseSchedule`) and the outputs
    have one more row: the rest, after the release (module docstring: each
    height differentiated as the schedule chose it, the put-down's root by the
    implicit function theorem on ``F_z = 0``); a pad's load steps by backward
    Euler (``Release.scheme``, :func:`_differentiated`): the rest row is that release's.

    Raises
    ------
    ValueError
        Not a Model or Commands, a release with a retreat,
        an unknown parameter, or a gripper stiffness with a rigid gripper.
    """
    if start is not None:
        if not isinstance(start, RolloutDerivatives) or not start.converged:
            raise ValueError("start must be a converged RolloutDerivatives")
        state, parameters = start.state, start.parameters
    commands, parameters = _check(model, commands, parameters, release)
    release = _differentiated(release)
    t0 = time.perf_counter()
    state = initial_state(model) if state is None else state
    K, n_par = len(commands), len(parameters)
    J = 4 * K + n_par + (release is not None)  # with a release, the last column: the current release step's height
    seeds = np.zeros((len(PARAMETERS), J))  # d parameter / d input
    for j, p in enumerate(parameters):
        seeds[PARAMETERS.index(p), 4 * K + j] = 1.0
    d_state = StateDerivative(np.zeros((model.mesh.n_dofs, J)), np.zeros((4, J)), np.zeros((3, J)))
    if start is not None:
        for name in ("displacement", "pose", "plate"):
            getattr(d_state, name)[:, 4 * K:4 * K + n_par] = getattr(start.parameter_state, name)
    rows = K + (release is not None)
    outputs, d_out, reports = np.zeros((rows, 9)), np.zeros((rows, 9, J)), []
    status, message = Status.CONVERGED, ""
    sequence = RecordingSequence(model, commands, state, release=release, consume_start=False)
    path = []  # (d height, d F_z) of the release's start, then of each release step
    for k, (new_state, report) in enumerate(sequence):
        if k == K:
            path.append((d_state.pose[2].copy(), d_out[K - 1, OUTPUTS.index("force_z")].copy()))
        result = _sequence_step(model, sequence, k, K, state, new_state, report, d_state, seeds, path)
        if isinstance(result[0], Status):
            status, message = result
            break
        state, d_state, row, d_row = result
        sequence.state = state  # with the tangent at the converged configuration
        reports.append(report)
        outputs[min(k, rows - 1)], d_out[min(k, rows - 1)] = row, d_row
        if k >= K:
            path.append((d_state.pose[2], d_row[OUTPUTS.index("force_z")]))
    n = min(len(reports), K) if status is not Status.CONVERGED else rows
    if release is not None and status is Status.CONVERGED:
        d_state = StateDerivative(*put_down_root(sequence.schedule, d_out[-1], OUTPUTS.index("force_z"),
                                                 (d_state.displacement, d_state.pose, d_state.plate)))
    tail = StateDerivative(*(getattr(d_state, k)[:, 4 * K:4 * K + n_par] for k in ("displacement", "pose", "plate")))
    return RolloutDerivatives(status, message, outputs[:n], d_out[:n, :, :4 * K].reshape(n, 9, K, 4),
                              d_out[:n, :, 4 * K:4 * K + n_par], parameters, state, tuple(reports), time.perf_counter() - t0,
                              tail)


def _sequence_step(model, sequence, k, K, state, new_state, report, d_state, seeds, path):
    """:func:`_step_derivative` of the ``k``-th step of ``sequence`` (a command's
    for ``k < K``, else a release step's), through the parts it was taken in:
    the halves of a frictional pad's step that failed whole, the parts a release
    step's error control kept; a part of a fraction ``f`` of the whole command
    moves with ``f`` times its derivative."""
    J = seeds.shape[1]
    d_whole = np.zeros((4, J))
    if k < K:
        d_whole[:, 4 * k:4 * k + 4] = np.eye(4)
        parts = _whole_steps(model, [(state, new_state, report)])
        sequence.taken = []
    else:  # a release step: its height as the schedule chose it; the last column is its own
        load = sequence.schedule.height_partials.get("load")  # a pad's load step: its height found with its load
        if load is None:
            d_whole[2] = release_height_derivative(model, sequence.schedule, d_state.pose[2], path,
                                                   seeds[PARAMETERS.index("young")],
                                                   seeds[PARAMETERS.index("density")])
            d_whole[2] -= d_state.pose[2]
        d_whole[2, -1] = 1.0
        for name in ("displacement", "pose", "plate"):
            getattr(d_state, name)[:, -1] = 0.0
        parts = _whole_steps(model, sequence.parts(new_state))
    if not parts:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: the parts it was taken in were not found"
    size = np.abs([report.command.dx, report.command.dy, report.command.dz, report.command.dtheta])
    c = int(np.argmax(size))
    for start, end, part in parts:
        fraction = 1.0 if size[c] == 0 else [part.command.dx, part.command.dy, part.command.dz,
                                             part.command.dtheta][c] / [report.command.dx, report.command.dy,
                                                                        report.command.dz, report.command.dtheta][c]
        result = _step_derivative(model, start, end, part, d_state, fraction * d_whole, seeds)
        if isinstance(result[0], Status):
            return result
        d_state = result[1]
    if k >= K and load:
        d_target = load[1] * -path[0][1] + load[2] * model.weight / model.material.density * \
            seeds[PARAMETERS.index("density")]
        state_, d_st, outputs_, d_row = result
        d_row, arrays = load_step_root(d_row, OUTPUTS.index("force_z"), load[0], d_target,
                                       (d_st.displacement, d_st.pose, d_st.plate))
        result = state_, StateDerivative(*arrays), outputs_, d_row
    if len(parts) == 1 and parts[0][1] is new_state:
        return result
    return new_state, result[1], result[2], result[3]


def _whole_steps(model, parts):
    """``parts`` (start, state, report) with every step that a frictional pad
    took in halves (:func:`~fe_contact.stepping.step.step`, its whole command
    having failed) replaced by its halves, taken again (the same steps), or
    None if one does not converge."""
    out = []
    for start, end, report in parts or []:
        if "half steps" not in report.message:
            out.append((start, end, report))
            continue
        half = half_command(report.command)
        middle, first = step(model, start, half)
        finish, second = step(model, middle, half)
        if not (first.converged and second.converged):
            return None
        out += _whole_steps(model, [(start, middle, first), (middle, finish, second)]) or [None]
    return None if None in out else out


@dataclass(frozen=True)
class StateDerivative:
    """Derivative of a state along J inputs: ``displacement`` (n_dofs, J), m;
    the commanded pose ``(t_x, t_y, t_z, theta)`` (4, J); the plate pose (3, J)."""

    displacement: np.ndarray
    pose: np.ndarray
    plate: np.ndarray


def _step_derivative(model, state, new_state, report, d_state, d_command, seeds):
    """The derivatives of the step from ``state`` that ended in ``(new_state,
    report)``: (state with the tangent at the converged configuration, d_state,
    outputs (9,), d_outputs (9, J)), or (status, message) if the step or its
    linearisation failed."""
    if not report.converged:
        return report.status, f"step {state.step_index + 1}: {report.message}"
    translation, rotation = commanded_pose(state, report.command)
    d_pose = d_state.pose + d_command
    if model.pad is not None:
        return _pad_step_derivative(model, state, new_state, report, d_state, d_pose, seeds, translation, rotation)
    lin = HeldLinearisation(model, state.displacement, report.displacement, report.reaction_local,
                            report.node_status)
    if lin.failure:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: {lin.failure}"
    J = d_pose.shape[1]
    if model.gripper.rigid:
        d_upper = upper_pose_jacobian(model, rotation) @ d_pose
        held = lin.solve(d_state.displacement, d_upper, seeds[:6])
        dU, d_force, d_plate = held.displacement, held.upper_force, d_pose[[0, 1, 3]]
    else:
        dU, d_force, d_plate = _compliant(model, state, report, lin, d_state, d_pose, seeds,
                                          np.array([translation[0], translation[1], rotation]))
    d_out = np.vstack([lower_pose_derivative(model, report.displacement, dU), d_force.sum(axis=0), d_plate])
    outputs = _report_outputs(report, new_state)
    new_state = replace(new_state, tangent=TangentCache(lin.tangent))  # the next step's start tangent
    return new_state, StateDerivative(dU, d_pose, d_plate), outputs, d_out.reshape(9, J)


def _pad_step_derivative(model, state, new_state, report, d_state, d_pose, seeds, translation, rotation):
    """:func:`_step_derivative` of a step with a frictional pad
    (:class:`~fe_contact.stepping.pad_sensitivity.PadLinearisation`)."""
    if "half steps" in report.message:  # split where the whole step failed: the halves' middle is not kept
        return Status.TANGENT_SINGULAR, (f"step {state.step_index + 1} was taken in halves ({report.message}): "
                                         "its derivative through them is not available")
    lin = PadLinearisation(model, state, report.displacement, np.vstack([report.reaction_local, report.pad_reaction]),
                           translation, rotation)
    if lin.failure:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: {lin.failure}"
    held = lin.solve_pad(d_state.displacement, d_state.pose, d_pose, seeds[:6])
    dU, d_plate = held.displacement, d_pose[[0, 1, 3]]
    d_out = np.vstack([lower_pose_derivative(model, report.displacement, dU), held.upper_force.sum(axis=0), d_plate])
    return new_state, StateDerivative(dU, d_pose, d_plate), _report_outputs(report, new_state), d_out


def _compliant(model, state, report, lin, d_state, d_pose, seeds, c):
    """Derivatives of a compliant-gripper step: the plate balance solved for ``dp``."""
    J = d_pose.shape[1]
    p = np.array(report.plate)
    Jp = upper_pose_jacobian(model, float(p[2]))  # (3 n_up, 4)
    zeros = np.zeros
    d_upper = np.hstack([np.outer(Jp[:, 2], d_pose[2]), Jp[:, [0, 1, 3]]])
    d_start = np.hstack([d_state.displacement, zeros((model.mesh.n_dofs, 3))])
    held = lin.solve(d_start, d_upper, np.hstack([seeds[:6], zeros((6, 3))]))
    f_upper = lin.f_int[model.upper_dofs].reshape(-1, 3)
    dF = plate_wrench_derivative(model, report.displacement, f_upper, held.displacement, held.upper_force)
    k = model.gripper.stiffness
    dk = np.vstack([seeds[6], seeds[6], seeds[7]])
    dc = d_pose[[0, 1, 3]]
    dp = np.linalg.solve(dF[:, J:] + np.diag(k), k[:, None] * dc + (c - p)[:, None] * dk - dF[:, :J])
    dU = held.displacement[:, :J] + held.displacement[:, J:] @ dp
    d_force = held.upper_force[:, :, :J] + held.upper_force[:, :, J:] @ dp
    return dU, d_force, dp


@dataclass(frozen=True)
class DerivativeCheck:
    """Exact derivatives against central differences (:func:`check_derivatives`).

    ``analytic``, ``numeric`` (n_steps * 9, n_inputs) as :meth:`RolloutDerivatives.jacobian`;
    ``error`` the entrywise relative error of the normalised Jacobian; ``inputs``,
    ``outputs`` the column and row names; ``steps`` the central-difference steps.
    """

    analytic: np.ndarray
    numeric: np.ndarray
    error: np.ndarray
    inputs: tuple
    outputs: tuple
    steps: np.ndarray

    @property
    def max_error(self) -> float:
        return float(self.error.max()) if self.error.size else 0.0

    def worst(self) -> str:
        i, j = np.unravel_index(int(np.argmax(self.error)), self.error.shape)
        return (f"{self.outputs[i]} / {self.inputs[j]}: exact {self.analytic[i, j]:.9g}, "
                f"central difference {self.numeric[i, j]:.9g} (error {self.error[i, j]:.2g})")


def check_derivatives(model: Model, commands, state: State | None = None, parameters=None,
                      rel_step: float = 1e-5, floor: float = 1e-4, release: Release | None = None) -> DerivativeCheck:
    """Compare :func:`rollout_derivatives` with central differences of rollouts
    (as MuJoCo's ``check_derivatives``).

    Input ``j`` is stepped by ``h_j = rel_step * s_j``, ``s_j`` its typical
    size (the largest command translation or rotation, ``|value|`` of a
    parameter, 1 rad for the angle).  The Jacobian is normalised, ``J_ij s_j /
    o_i`` (``o_i`` the largest value of output kind ``i`` over the rollout:
    lengths, angles, forces), and the error of an entry is ``|exact - central|
    / max(|central|, floor * max |central|)``: entries far below the dominant
    sensitivity are compared at ``floor`` of it.  (Lengths are scaled by at
    least the largest command translation, angles by at least that over the
    block's size.)  The step trades the central differences' own ``h^2`` error
    against the solvers' noise divided by ``h``: 1e-5 suits soft blocks at
    tight tolerances, a steel block wants 1e-4 (measured on a 3 x 2 x 2 steel
    block: 1.6e-5, 4.7e-7, 3.7e-6 at 1e-3, 1e-4, 1e-5).  The central differences'
    rollouts run without Anderson's mixing (``SolverOptions.acceleration`` 0): its
    discrete choices (mix, plain, reject) make a converged state's error a
    non-smooth function of the input at the tolerance's level, which the
    differences divide by ``h`` (measured on a sliding 2 x 2 x 1 block at
    ``newton_tol`` 1e-13: error 2.4e-6 with it, 3e-7 without; 1.8e-5 and 4e-7 at 1e-12).

    Raises
    ------
    ValueError
        As :func:`rollout_derivatives`, or a rollout that does not converge.
    """
    commands, parameters = _check(model, commands, parameters, release)
    release = _differentiated(release)
    exact = rollout_derivatives(model, commands, state, parameters, release=release)
    if not exact.converged:
        raise ValueError(f"the rollout does not converge: {exact.message}")
    arr = np.array([[c.dx, c.dy, c.dz, c.dtheta] for c in commands])
    size = max(model.mesh.size)
    move = max(float(np.abs(arr[:, :3]).max()), size * 1e-4)
    turn = max(float(np.abs(arr[:, 3]).max()), move / size)
    values = parameter_values(model)
    typical = [move, move, move, turn] * len(commands) + [1.0 if p == "angle" else abs(values[p])
                                                          for p in parameters]
    typical = np.array(typical)
    steps = rel_step * typical

    smooth = model if model.options.acceleration == 0 else replace(
        model, options=replace(model.options, acceleration=0))

    def outputs(j, h):
        cmds, mdl = list(commands), smooth
        if j < 4 * len(commands):
            k, c = divmod(j, 4)
            cmds[k] = replace(cmds[k], **{COMPONENTS[c]: getattr(cmds[k], COMPONENTS[c]) + h})
        else:
            p = parameters[j - 4 * len(commands)]
            mdl = with_parameters(smooth, **{p: values[p] + h})
        return _plain(mdl, cmds, state, release)

    numeric = np.column_stack([(outputs(j, h) - outputs(j, -h)).ravel() / (2 * h) for j, h in enumerate(steps)])
    analytic = exact.jacobian()
    o = np.abs(exact.outputs)
    kind = np.array([0, 0, 1, 2, 2, 2, 0, 0, 1])
    scale = np.maximum([o[:, kind == g].max() for g in range(3)], [move, move / size, 1e-300])[kind]
    norm = np.tile(scale, exact.outputs.shape[0])[:, None]
    A, N = analytic * typical / norm, numeric * typical / norm
    err = np.abs(A - N) / np.maximum(np.abs(N), floor * np.abs(N).max())
    names_in = tuple(f"{c}[{k}]" for k in range(len(commands)) for c in COMPONENTS) + tuple(parameters)
    names_out = tuple(f"{o}[{k if k < len(commands) else 'rest'}]" for k in range(exact.outputs.shape[0])
                      for o in OUTPUTS)
    return DerivativeCheck(analytic, numeric, err, names_in, names_out, steps)


def _plain(model, commands, state, release=None) -> np.ndarray:
    """Outputs (n_steps, 9) of a plain rollout, and with ``release`` one more
    row: the rest; ValueError if a step fails."""
    start = None if state is None else replace(state, tangent=None)
    out = []
    for k, (state, report) in enumerate(StepSequence(model, commands, start, release=release)):
        if not report.converged:
            raise ValueError(f"central difference: step {k + 1} did not converge: {report.message}")
        if k < len(commands) or release is None:
            out.append(_report_outputs(report, state))
    if release is not None:
        out.append(_report_outputs(report, state))
    return np.array(out)


def _report_outputs(report: StepReport, state: State) -> np.ndarray:
    """:data:`OUTPUTS` of a converged step (9,) ending in ``state`` (the plate
    pose of the state: a rigid drive's report carries the start's)."""
    return np.concatenate([report.lower_centroid[:2], [report.lower_yaw], report.upper_force, state.plate])


__all__ = ["COMPONENTS", "PARAMETERS", "OUTPUTS", "RolloutDerivatives", "DerivativeCheck", "applicable_parameters",
           "check_derivatives", "parameter_values", "rollout_derivatives", "with_parameters"]
