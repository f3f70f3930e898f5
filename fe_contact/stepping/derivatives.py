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

A release (``release=Release("lift", n)``) adds one row, the rest after
it, differentiated as the discrete map the release schedule took
(:mod:`~fe_contact.stepping.release_derivatives`: a pad's load steps as they ran,
by the implicit midpoint rule or backward Euler); a compliant gripper's
plate with a frictional pad is eliminated by its balance in each step
(:func:`~fe_contact.stepping.pad_sensitivity.solve_compliant_pad`).  A
release with a retreat is not differentiated.

Where a contact ends a step at a transition of the contact law
(:mod:`~fe_contact.stepping.transitions`: an input change of
``TRANSITION_TOL`` of its size changes its branch), the outputs from that
step on have no derivative along that input: those entries are NaN and
:attr:`RolloutDerivatives.transitions` says where and why.  The central
differences' check is :mod:`~fe_contact.stepping.derivative_check`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..fem.loads import Gripper
from .model import Command, Friction, Model, State, Status, initial_state
from .release import Release, rest_check
from .command import LetGo, PadLoad
from .release_derivatives import (LoadStep, RecordingSequence, load_step_derivative, put_down_root,
                                  release_height_derivative, whole_steps)
from .step_derivative import StateDerivative, step_derivative
from .transitions import Transition, flipping_inputs, summary

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
        ``d outputs[k, i] / d commands[j, c]`` (zero for ``j > k``); NaN
        where there is no derivative (:attr:`transitions`).
    d_parameters : ndarray, shape (n_steps, 9, n_parameters)
        Derivatives with respect to ``parameters`` (NaN likewise).
    parameters : tuple of str
    state : State
        Final state.
    reports : tuple of StepReport
    wall_time : float
        s.
    parameter_state : StateDerivative
        Derivatives of the final state with respect to ``parameters`` (to
        continue the rollout: ``rollout_derivatives(..., start=this)``).
    transitions : tuple of Transition
        The contacts that ended a step at a transition of the contact law
        (:mod:`~fe_contact.stepping.transitions`), each with the inputs along
        which the outputs from that step on have no derivative.
    rest : Rest or None
        With a release: whether the block settled
        (:func:`~fe_contact.stepping.release.rest_check`).
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
    transitions: tuple = ()
    rest: object = None

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def differentiable(self) -> bool:
        """Every derivative exists (no contact at a transition; a failed rollout is not)."""
        return self.converged and not self.transitions

    @property
    def inputs(self) -> tuple:
        """The column names of :meth:`jacobian`: ``dx[0], dy[0], ...``, then the parameters."""
        K = self.d_commands.shape[2]
        return tuple(f"{c}[{k}]" for k in range(K) for c in COMPONENTS) + tuple(self.parameters)

    def nondifferentiable(self, columns=None) -> str:
        """Why some derivatives do not exist ("" if they all do): the contacts at
        a transition, by step and kind (:func:`~fe_contact.stepping.transitions.summary`).
        ``columns`` (indices into :attr:`inputs`; default all): the inputs a caller
        varies (a planner's in-plane commands, without ``dz``); only those are named,
        and a transition along none of them is left out (its derivatives are not asked)."""
        transitions = self.transitions
        if columns is not None:
            keep = set(columns)
            transitions = tuple(t for t in (replace(t, inputs=tuple(j for j in t.inputs if j in keep))
                                             for t in transitions) if t.inputs)
        return summary(transitions, self.inputs)

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


def input_sizes(model: Model, commands, parameters) -> np.ndarray:
    """Typical size of each input (4 K + n_parameters,): the largest command
    translation (at least 1e-4 of the block) for ``dx, dy, dz``, the largest
    turn (at least that translation over the block's size) for ``dtheta``,
    ``|value|`` of a parameter, 1 rad for the angle; SI."""
    arr = np.array([[c.dx, c.dy, c.dz, c.dtheta] for c in commands]).reshape(-1, 4)
    size = max(model.mesh.size)
    move = max(float(np.abs(arr[:, :3]).max(initial=0.0)), size * 1e-4)
    turn = max(float(np.abs(arr[:, 3]).max(initial=0.0)), move / size)
    values = parameter_values(model)
    return np.array([move, move, move, turn] * len(commands)
                    + [1.0 if p == "angle" else abs(values[p]) for p in parameters])


def _check(model, commands, parameters, release=None, pad: bool = True) -> tuple[list, tuple]:
    if not isinstance(model, Model):
        raise ValueError(f"model must be a Model, got {type(model).__name__}")
    if release is not None and (not isinstance(release, Release) or release.mode != "lift"
                                or any(getattr(release, "away", (0.0, 0.0)))):
        raise ValueError(f"release must be a Release of mode 'lift' straight up (an open release, or a retreat "
                         f"away, is not differentiated), got {release!r}")
    if model.pad is not None and not pad:
        raise ValueError("a frictional pad is not differentiated in reverse mode: use rollout_derivatives")
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


@dataclass
class _Run:
    """The forward sweep's running values: the state derivative, the outputs and their derivatives so far."""

    d_state: "StateDerivative"
    seeds: np.ndarray  # d parameter / d input (len(PARAMETERS), J)
    typical: np.ndarray  # (J,) the inputs' sizes; 0 for the release's own height column
    outputs: np.ndarray
    d_out: np.ndarray
    path: list  # (d height, d F_z) of the release's start, then of each release step
    transitions: list


def _start(model, commands, parameters, start, release) -> _Run:
    """The sweep's inputs: ``4 K`` command columns, the parameters', and with a
    release one more, the current release step's own height."""
    K, n_par = len(commands), len(parameters)
    J = 4 * K + n_par + (release is not None)
    seeds = np.zeros((len(PARAMETERS), J))
    for j, p in enumerate(parameters):
        seeds[PARAMETERS.index(p), 4 * K + j] = 1.0
    d_state = StateDerivative(np.zeros((model.mesh.n_dofs, J)), np.zeros((4, J)), np.zeros((3, J)),
                              np.zeros((model.n_contacts, 3, J)))
    if start is not None:
        for name in ("displacement", "pose", "plate"):
            getattr(d_state, name)[:, 4 * K:4 * K + n_par] = getattr(start.parameter_state, name)
        if start.parameter_state.reaction is not None:
            d_state.reaction[..., 4 * K:4 * K + n_par] = start.parameter_state.reaction
    typical = np.zeros(J)
    typical[:4 * K + n_par] = input_sizes(model, commands, parameters)
    rows = K + (release is not None)
    return _Run(d_state, seeds, typical, np.zeros((rows, 9)), np.zeros((rows, 9, J)), [], [])


def rollout_derivatives(model: Model, commands, state: State | None = None, parameters=None,
                        start: RolloutDerivatives | None = None, release: Release | None = None) -> RolloutDerivatives:
    """Run ``commands`` from ``state`` (default: the undeformed block) and
    differentiate every output of every step (module docstring).

    ``state`` is held fixed: its own dependence on the parameters is not
    included.  To include it, give instead ``start``, an earlier converged
    result of this model (e.g. the press), whose final state and parameters
    the rollout continues from.  With ``release`` (a ``"lift"`` straight up, of the bonded
    or a frictional pad), the block is let go after the commands and the outputs have one
    more row: the rest (module docstring: each height as the schedule chose it, the
    put-down's root by the implicit function theorem on ``F_z = 0``), ``rest`` whether it
    settled; a pad's load steps as the release takes them (``Release.scheme``: the implicit
    midpoint rule or backward Euler, :func:`~fe_contact.stepping.release_derivatives.load_step_derivative`).

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
    t0 = time.perf_counter()
    state = initial_state(model) if state is None else state
    run = _start(model, commands, parameters, start, release)
    sequence = RecordingSequence(model, commands, state, release=release, consume_start=False)
    status, message, state, reports, pending = _sweep(model, sequence, len(commands), state, run)
    return _result(model, commands, parameters, sequence, run, (status, message, state, reports, pending),
                   release, t0)


def _sweep(model, sequence, K, state, run: _Run):
    """The forward sweep through every step of ``sequence``; returns (status,
    message, final state, reports, the last step's margins not yet checked:
    a put-down's root corrects them first)."""
    force_z = OUTPUTS.index("force_z")
    status, message, reports, pending = Status.CONVERGED, "", [], None
    rows = run.outputs.shape[0]
    for k, (new_state, report) in enumerate(sequence):
        if pending is not None:  # the previous step was not the last: its transitions before this step
            _mark(run, *pending)
        if k == K:
            run.path.append((run.d_state.pose[2].copy(), run.d_out[K - 1, force_z].copy()))
        result = _sequence_step(model, sequence, k, K, state, new_state, report, run)
        if isinstance(result[0], Status):
            status, message, pending = *result, None
            break
        state, run.d_state, row, d_row, found = result
        sequence.state = state  # with the tangent at the converged configuration
        reports.append(report)
        run.outputs[min(k, rows - 1)], run.d_out[min(k, rows - 1)] = row, d_row
        pending = (len(reports), found, min(k, rows - 1))
        if k >= K:
            run.path.append((run.d_state.pose[2], d_row[force_z]))
    return status, message, state, reports, pending


def _mark(run: _Run, step_number: int, found: list, row: int) -> None:
    """The transitions of step ``step_number`` (1-based; its margins ``found``,
    their derivatives along the inputs): the inputs along which a contact
    changes branch lose their derivatives (NaN) in the state and in the
    outputs from ``row`` on."""
    for m, dm, kind, skip in found:
        flips, transitions = flipping_inputs(step_number, m, dm.reshape(m.shape + (-1,)), kind, run.typical, skip)
        if not flips.any():
            continue
        run.transitions += transitions
        for x in (run.d_state.displacement, run.d_state.pose, run.d_state.plate):
            x[:, flips] = np.nan
        if run.d_state.reaction is not None:
            run.d_state.reaction[..., flips] = np.nan
        run.d_out[row:, :, flips] = np.nan


def _result(model, commands, parameters, sequence, run: _Run, swept, release, t0) -> RolloutDerivatives:
    """The :class:`RolloutDerivatives` of a finished sweep: a put-down's root, the last step's transitions, the rest."""
    status, message, state, reports, pending = swept
    K, n_par, rows = len(commands), len(parameters), run.outputs.shape[0]
    n = min(len(reports), K) if status is not Status.CONVERGED else rows
    d_state, rest = run.d_state, None
    if release is not None and status is Status.CONVERGED:
        m, dm, kind, skip = pending[1][-1]
        arrays = put_down_root(sequence.schedule, run.d_out[-1], OUTPUTS.index("force_z"),
                               (d_state.displacement, d_state.pose, d_state.plate, dm.reshape(-1, dm.shape[-1])))
        run.d_state = StateDerivative(*arrays[:3], d_state.reaction)
        pending[1][-1] = (m, arrays[3].reshape(dm.shape), kind, skip)
        rest = rest_check(model, state, reports[-1], sequence.schedule)
    if pending is not None:
        _mark(run, *pending)
    reaction = None if run.d_state.reaction is None else run.d_state.reaction[..., 4 * K:4 * K + n_par]
    tail = StateDerivative(*(getattr(run.d_state, k)[:, 4 * K:4 * K + n_par]
                             for k in ("displacement", "pose", "plate")), reaction)
    d_out = run.d_out
    return RolloutDerivatives(status, message, run.outputs[:n], d_out[:n, :, :4 * K].reshape(n, 9, K, 4),
                              d_out[:n, :, 4 * K:4 * K + n_par], parameters, state, tuple(reports),
                              time.perf_counter() - t0, tail, tuple(run.transitions), rest)


def _sequence_step(model, sequence, k, K, state, new_state, report, run: _Run):
    """:func:`~fe_contact.stepping.step_derivative.step_derivative` of the ``k``-th step of ``sequence`` (a command's
    for ``k < K``, else a release step's), through the parts it was taken in:
    the halves of a frictional pad's step that failed whole, the parts a release
    step's error control kept (a part of a fraction ``f`` of the whole command
    moves with ``f`` times its derivative); a pad's load step as it was taken
    (:func:`~fe_contact.stepping.release_derivatives.load_step_derivative`).
    Returns (state, d_state, outputs, d_outputs, the margins of its contacts), or (status, message)."""
    if isinstance(report.command, LetGo):
        return Status.TANGENT_SINGULAR, (f"step {state.step_index + 1}: a bonded pad's let-go (an offset pad that "
                                         "still held the block in the plane) is not differentiated")
    d_state, seeds = run.d_state, run.seeds
    d_whole, load = _whole_command(model, sequence, k, K, d_state, seeds, run.path)
    if load is not None:  # a pad's load step: backward Euler or the midpoint rule
        taken = list(sequence.taken)
        step = LoadStep(load[0], _load_derivative(model, load, run), run.d_out[min(k - 1, len(run.d_out) - 1)],
                        sequence.schedule.midpoint(PadLoad(load[0])), OUTPUTS.index("force_z"), seeds)
        return load_step_derivative(model, taken, sequence.parts(new_state), state, new_state, report, step,
                                    d_state)
    taken = [(state, new_state, report)] if k < K else sequence.parts(new_state)
    parts = whole_steps(model, taken)
    if k < K:
        sequence.taken = []
    if not parts:
        return Status.TANGENT_SINGULAR, f"step {state.step_index + 1}: the parts it was taken in were not found"
    size = _command_array(report.command)
    c = int(np.argmax(np.abs(size)))
    found = []
    for start, end, part in parts:
        fraction = 1.0 if size[c] == 0 else _command_array(part.command)[c] / size[c]
        result = step_derivative(model, start, end, part, d_state, fraction * d_whole, seeds)
        if isinstance(result[0], Status):
            return result
        d_state = result[1]
        found.append(result[4])
    if len(parts) == 1 and parts[0][1] is new_state:
        return result[:4] + (found,)
    return new_state, result[1], result[2], result[3], found


def _command_array(command) -> np.ndarray:
    return np.array([command.dx, command.dy, command.dz, command.dtheta])


def _whole_command(model, sequence, k, K, d_state, seeds, path):
    """The derivative (4, J) of the ``k``-th step's whole command and, for a pad's
    load step, its schedule's ``(load, d load / d loaded, d load / d weight)``."""
    d_whole = np.zeros((4, seeds.shape[1]))
    if k < K:
        d_whole[:, 4 * k:4 * k + 4] = np.eye(4)
        return d_whole, None
    # a release step: its height as the schedule chose it; the last column is its own
    load = sequence.schedule.height_partials.get("load")  # a pad's load step: its height found with its load
    if load is None:
        d_whole[2] = release_height_derivative(model, sequence.schedule, d_state.pose[2], path,
                                               seeds[PARAMETERS.index("young")], seeds[PARAMETERS.index("density")])
        d_whole[2] -= d_state.pose[2]
    d_whole[2, -1] = 1.0
    for name in ("displacement", "pose", "plate"):
        getattr(d_state, name)[:, -1] = 0.0
    if d_state.reaction is not None:
        d_state.reaction[..., -1] = 0.0
    return d_whole, load


def _load_derivative(model, load, run: _Run) -> np.ndarray:
    """The derivative (J,) of a pad's load step's load ``P_k`` of the schedule
    (``load`` its ``(P_k, dP_k / dP_0, dP_k / dW)``): of the loaded load ``P_0 =
    -F_z`` of the release's start and of the weight ``rho g V``."""
    return load[1] * -run.path[0][1] + load[2] * model.weight / model.material.density * \
        run.seeds[PARAMETERS.index("density")]


__all__ = ["COMPONENTS", "PARAMETERS", "OUTPUTS", "RolloutDerivatives", "Transition", "applicable_parameters",
           "input_sizes", "parameter_values", "rollout_derivatives", "with_parameters"]
