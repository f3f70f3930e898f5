"""The held step: equilibrium of the block with its upper face held by the
gripper plate at a given pose (the rigid drive, and each trial pose of the
compliant gripper), and the state a converged step ends in.

Shared by :mod:`fe_contact.stepping.step`, :mod:`~fe_contact.stepping.gripper`
and :mod:`~fe_contact.stepping.release`, below all three.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..fem.loads import NO_LOADING, Loading
from .law_check import checked
from .measure import SEPARATION_FORCE, measure
from .model import Command, Model, State, Status, StepReport, TangentCache
from .newton import Equilibrium, equilibrium
from .predictor import StepGuess, guessed_start, upper_face_displacement


def held_step(model: Model, state: State, command: Command, translation: np.ndarray, rotation: float,
              t0: float, local_problem_hook=None, consume: bool = False,
              extra: dict | None = None, guess: StepGuess | None = None) -> tuple[Equilibrium, StepReport]:
    """Equilibrium and report of a step with the upper face held by the plate
    at pose ``(translation, rotation)`` (the rigid drive; the compliant
    gripper's trial poses).  A frictional pad that carries nothing at the
    step's start and rises drags nothing: the Newton loop starts at the state
    (the predictor would stretch the block by the rise: measured 144 Newton
    iterations for a 5 mm rise after a release, 1-2 from the state).

    ``guess`` (:class:`~fe_contact.stepping.predictor.StepGuess`, without a
    frictional pad only) starts the loop at the guessed displacements and contact
    forces; if the loop does not converge from there, the step is solved again
    from the predictor (a guess never fails a step that converges without it: at
    most two Newton loops; with ``consume`` the second may start without the
    state's cached tangent, which the first released)."""
    pad_normal = state.reaction[model.n_lower:, 0]
    open_pad = model.pad is not None and command.dz >= 0 and pad_normal.size > 0 and \
        bool(np.all(pad_normal <= SEPARATION_FORCE * np.abs(state.reaction).max()))
    guess = guess if model.pad is None else None
    U = np.array(state.displacement, dtype=float) if open_pad else guessed_start(model, state, command, guess)
    if model.pad is None:
        U[model.held_nodes] = upper_face_displacement(model, translation, rotation)
        loading, gripper = held_loading(model), None
    else:
        loading, gripper = pad_loading(model, state), (translation, pad_motion(model, state, translation, rotation))
    eq = equilibrium(model, state, U, local_problem_hook, consume, loading, gripper, guess=guess)
    if guess is not None and eq.status is not Status.CONVERGED:  # the guess misled it: from the predictor
        return held_step(model, state, command, translation, rotation, t0, local_problem_hook, consume, extra)
    return eq, checked(model, measure(model, state, command, eq, t0, loading, extra))


def let_go_step(model: Model, state: State, command: Command, t0: float, local_problem_hook=None,
                consume: bool = False) -> tuple[State, StepReport]:
    """The step in which a bonded pad lets go (:class:`~fe_contact.stepping.command.LetGo`):
    the upper face free (``model.released()``), the gripper where it is, the
    block in equilibrium under its weight and the floor's contacts alone.
    Every dof is free: the proximal springs of :func:`pad_loading` make the
    flexibility matrix exist and exert no force at convergence, so the
    converged step solves the unregularised problem; the Newton loop starts
    at the state (the pad's residual forces are what it removes).  Returns the
    new state (``state`` if the step failed) and the report (``upper_force``
    zero: nothing holds the face)."""
    free = model.released()
    loading = pad_loading(free, state)
    eq = equilibrium(free, state, np.array(state.displacement, dtype=float), local_problem_hook, consume, loading)
    report = checked(free, measure(free, state, command, eq, t0, loading))
    if not report.converged:
        return state, report
    return next_state(state, eq, state.upper_translation, state.upper_rotation, report), report


def held_loading(model: Model) -> Loading:
    """The applied loads of a held step: the self-weight, if any."""
    return NO_LOADING if model.body_force is None else Loading(external=model.body_force)


def pad_loading(model: Model, state: State) -> Loading:
    """The loads of a step with a frictional pad: the self-weight and
    proximal springs on every dof,

        K_reg = k_a I,    k_a = beta k_shear V_a / V,    N/m,

    ``beta = SolverOptions.pad_regularisation``, ``k_shear = G A / H``, ``V_a``
    the nodal volume.  Held by two frictional planes, the free block's
    stiffness is singular in its rigid modes and the flexibility matrix needs
    them regularised; the springs are anchored at each Newton iterate
    (``Loading.proximal``), so they damp the corrections and exert no force
    at convergence: the converged step solves the unregularised problem
    (tested: the answer does not move when ``beta`` is divided by 10).  The
    tangent keeps the geometric stiffness of the tensile stresses only
    (positive definite: a compressed free block's consistent tangent is
    indefinite in its rigid rotations)."""
    k = model.options.pad_regularisation * model.shear_stiffness * model.nodal_volume / model.nodal_volume.sum()
    return Loading(external=model.body_force, spring=np.repeat(k, 3),
                   anchor=np.array(state.displacement, dtype=float).ravel(), diagonal=model.diagonal,
                   tension_only_geometric=True, proximal=True)


def pad_motion(model: Model, state: State, translation: np.ndarray, rotation: float) -> np.ndarray:
    """Increment over the step of the pad's point at each contact node
    (n_contacts, 3), m: the rigid motion of the pad from the state's pose to
    ``(translation, rotation)`` (rotation about the pad's centre, as
    :func:`~fe_contact.stepping.predictor.upper_face_displacement`); zero for
    the floor's contacts."""
    nodes, n_lower = model.contacts.nodes, model.n_lower
    x = model.mesh.nodes[nodes[n_lower:]] + state.displacement[nodes[n_lower:]]
    centre = model.upper_centre + state.upper_translation
    dtheta = rotation - state.upper_rotation
    c, s = np.cos(dtheta), np.sin(dtheta)
    rel = x - centre
    moved = np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1], rel[:, 2]])
    motion = np.zeros((nodes.size, 3))
    motion[n_lower:] = moved - rel + (translation - state.upper_translation)
    return motion


def next_state(state: State, eq: Equilibrium, translation: np.ndarray, rotation: float,
               report: StepReport, **changes) -> State:
    """The state a converged step ends in, with its own cache of ``eq``'s
    tangent; ``changes`` sets ``plate``."""
    return State(
        displacement=eq.displacement,
        reaction=eq.reaction,
        upper_translation=translation,
        upper_rotation=rotation,
        slip_path=report.slip_path,
        step_index=state.step_index + 1,
        tangent=TangentCache(eq.tangent),
        **changes,
    )


def joined_report(state: State, first: StepReport, second: StepReport, command: Command, message: str,
                  combine=sum) -> StepReport:
    """The report of a step taken in two parts from ``state``: the second
    part's, with the whole ``command``, both parts' slip increments, their
    Newton iterations combined by ``combine`` (``sum``: the cost; ``max``: the
    longest Newton loop), and ``message``, followed by what the parts' own
    messages say beyond "converged" (a part solved to the release's path
    tolerance, or to rounding, says so)."""
    notes = list(dict.fromkeys(m for m in (first.message, second.message) if m != "converged"))
    message = "; ".join([message, *(f"part: {m}" for m in notes)])
    return replace(second, command=command, step_index=state.step_index + 1,
                   newton_iterations=combine((first.newton_iterations, second.newton_iterations)),
                   slip_increment=first.slip_increment + second.slip_increment, message=message)
