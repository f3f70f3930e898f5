"""The held step: equilibrium of the block with its upper face held by the
gripper plate at a given pose (the rigid drive, and each trial pose of the
compliant gripper), and the state a converged step ends in.

Shared by :mod:`fe_contact.stepping.step`, :mod:`~fe_contact.stepping.gripper`
and :mod:`~fe_contact.stepping.release`, below all three.
"""

from __future__ import annotations

import numpy as np

from ..fem.loads import NO_LOADING, Loading
from .measure import measure
from .model import Command, Model, State, StepReport, TangentCache
from .newton import Equilibrium, equilibrium
from .predictor import predictor, upper_face_displacement


def held_step(model: Model, state: State, command: Command, translation: np.ndarray, rotation: float,
              t0: float, local_problem_hook=None, consume: bool = False,
              extra: dict | None = None) -> tuple[Equilibrium, StepReport]:
    """Equilibrium and report of a step with the upper face held by the plate
    at pose ``(translation, rotation)`` (the rigid drive; the compliant
    gripper's trial poses)."""
    U = predictor(model, state, command)
    U[model.mesh.upper] = upper_face_displacement(model, translation, rotation)
    loading = held_loading(model)
    eq = equilibrium(model, state, U, local_problem_hook, consume, loading)
    return eq, measure(model, state, command, eq, t0, loading, extra)


def held_loading(model: Model) -> Loading:
    """The applied loads of a held step: the self-weight, if any."""
    return NO_LOADING if model.body_force is None else Loading(external=model.body_force)


def next_state(state: State, eq: Equilibrium, translation: np.ndarray, rotation: float,
               report: StepReport, **changes) -> State:
    """The state a converged step ends in, with its own cache of ``eq``'s
    tangent; ``changes`` sets ``plate``, ``grip``, ``upper_load``."""
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
