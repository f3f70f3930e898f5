"""Start of a step: the commanded pose of the upper face and the predictor of
the Newton loop, or a guessed start from a converged step like it (:class:`StepGuess`).

The upper face is prescribed: for a cumulative translation ``t`` (3,) m and
rotation ``theta`` rad about the vertical axis through the translated centre
of the upper face, an upper-face node at ``X`` goes to

    x = c + R_z(theta) (X - c) + t,    c the reference centre of the upper face,

and its displacement is ``x - X``.  The rest of the block starts from the
previous state carried rigidly by the command's in-plane motion and
compressed homogeneously by its ``dz`` (:func:`predictor`).  Displacements are
arrays (n_nodes, 3), m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .command import PadLoad
from .model import Command, Model, State


def commanded_pose(state: State, command: Command) -> tuple[np.ndarray, float]:
    """Cumulative pose of the upper face after ``command``: translation (3,), m,
    and rotation about z, rad."""
    translation = state.upper_translation + np.array([command.dx, command.dy, command.dz])
    return translation, state.upper_rotation + command.dtheta


def upper_face_displacement(model: Model, translation: np.ndarray, rotation: float) -> np.ndarray:
    """Displacement of the held upper-face nodes (``model.held_nodes``: those
    under the pad's footprint) for a rigid pose of the upper face.

    Parameters
    ----------
    translation : ndarray, shape (3,)
        Cumulative translation of the upper face, m.
    rotation : float
        Cumulative rotation about the vertical axis through the (translated)
        upper-face centre, rad.

    Returns
    -------
    ndarray, shape (n_held, 3)
    """
    X = model.mesh.nodes[model.held_nodes]
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
    centre = model.upper_centre[:2] + state.plate[:2]  # the plate's pose (the commanded one if rigid)
    cs, sn = math.cos(command.dtheta), math.sin(command.dtheta)
    rel = x[:, :2] - centre
    U = np.array(state.displacement, dtype=float)
    U[:, 0] += cs * rel[:, 0] - sn * rel[:, 1] - rel[:, 0] + command.dx
    U[:, 1] += sn * rel[:, 0] + cs * rel[:, 1] - rel[:, 1] + command.dy
    Z = model.mesh.nodes[:, 2]
    U[:, 2] += command.dz * (Z - Z.min()) / (Z.max() - Z.min())
    return U


@dataclass(frozen=True)
class StepGuess:
    """A start for a step's Newton loop taken from a converged step like it (the same
    push of an earlier rollout of nearly the same commands, from nearly the same state).

    ``correction`` (n_nodes, 3), m: that step's converged displacement less its own
    :func:`predictor`, the part of the answer the rigid carry does not give (the
    block's elastic lag and where its lower face stuck or slid); ``reaction``
    (n_contacts, 3), N, local ``(n, t_x, t_y)``: its converged contact forces.  The
    guessed start of a step is its own predictor plus ``correction``, with
    ``reaction`` as the first contact forces (:func:`guessed_start`): for the same
    start and command it is the earlier step's answer itself, for a small change of
    either, that answer moved with them.  ``tangent`` (optional, a
    :class:`~fe_contact.stepping.tangent.Tangent` of the same model) is the tangent
    that step ended with, kept by the modified Newton loop instead of the start
    state's (a tangent near this step's answer, not its start: fewer iterations and
    refreshes; a guess holding one keeps its factors alive).  Only where the Newton
    loop starts: the step converges to the same tolerances
    (``SolverOptions.newton_tol``, ``local_tol``), its convergence test unchanged.
    A frictional pad's load step (:class:`~fe_contact.stepping.command.PadLoad`,
    :func:`load_path_guess`) has no predictor but its start's displacements, which
    ``correction`` adds to; ``height`` (m, or None: the start's) is where its pad's
    height, an unknown of the loop, starts.
    """

    correction: np.ndarray
    reaction: np.ndarray
    tangent: object = None
    height: float | None = None

    @classmethod
    def of(cls, model: Model, start: State, command: Command, end: State, tangent=None) -> "StepGuess":
        """The guess a converged step from ``start`` by ``command`` to ``end`` gives, with
        ``tangent``, the one that step ended with (``end.tangent.value`` before a later
        step released it), to keep."""
        return cls(end.displacement - predictor(model, start, command), np.array(end.reaction, dtype=float), tangent)

    def check(self, model: Model) -> None:
        """ValueError unless the arrays have the model's shapes and are finite and the
        tangent, if any, is one of the model's free dofs and contacts."""
        for name, shape in (("correction", (model.mesh.n_nodes, 3)), ("reaction", (model.n_contacts, 3))):
            a = getattr(self, name)
            if not isinstance(a, np.ndarray) or a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"guess.{name} must be a finite array of shape {shape}, got "
                                 f"{getattr(a, 'shape', type(a).__name__)}")
        t = self.tangent
        if t is not None and (getattr(t, "n_free", None) != model.free_dofs.size
                              or getattr(t, "W_scaled", np.zeros(0)).shape != (3 * model.n_contacts,) * 2):
            raise ValueError(f"guess.tangent must be a tangent of this model's {model.free_dofs.size} free dofs "
                             f"and {model.n_contacts} contacts, got {type(t).__name__}")


def guessed_start(model: Model, state: State, command, guess: StepGuess | None) -> np.ndarray:
    """The start of a step's Newton loop (n_nodes, 3), m: :func:`predictor` (a
    :class:`~fe_contact.stepping.command.PadLoad`: ``state``'s displacements), plus
    ``guess.correction`` when there is a guess."""
    U = np.array(state.displacement, dtype=float) if isinstance(command, PadLoad) else predictor(model, state, command)
    if guess is not None:
        U += guess.correction
    return U


MAX_LOAD_EXTRAPOLATION = 4.0
""":func:`load_path_guess` extrapolates a load step by at most this many times the step it extrapolates."""


def load_path_guess(before: State, after: State, loads: tuple[float, float], load: float) -> StepGuess | None:
    """The start of a frictional pad's load step from ``after`` to the pad load
    ``load`` (N): the path of the load step ``before -> after`` (their pad loads
    ``loads = (P_0, P_a)``, N) extrapolated linearly in the load,

        S = S_a + s (S_a - S_0),    s = (P - P_a) / (P_a - P_0),

    ``S`` the displacements, the contact forces and the pad's height.  Between
    changes of a contact's state the unloading path is smooth in the load, so this
    start is off by ``O(s^2)`` of the last step where the start alone (the first
    correction a linearised step, damped by the pad's proximal springs,
    :func:`~fe_contact.stepping.held.pad_loading`) is off by ``O(s)``.  Only the
    Newton loop's start: the step converges to the same tolerances.  None where
    the last step did not change the load, or ``s`` is not in ``(0,
    MAX_LOAD_EXTRAPOLATION]``."""
    step = loads[1] - loads[0]
    s = (load - loads[1]) / step if step != 0 else math.nan
    if not 0 < s <= MAX_LOAD_EXTRAPOLATION:
        return None
    height = float(after.upper_translation[2] + s * (after.upper_translation[2] - before.upper_translation[2]))
    return StepGuess(s * (after.displacement - before.displacement), after.reaction + s * (after.reaction - before.reaction),
                     height=height)
