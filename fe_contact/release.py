"""Release of the block after the last load step: the gripper lifts, or opens.

``lift``: the gripper keeps its in-plane command and rises: ``steps`` increments
``dz = d / steps`` summing to the press depth ``d = -t_z`` (``t_z`` the
upper face's cumulative vertical translation), then further increments of
``d / steps`` while the upper face still pushes on the block
(``upper_force_z < -LIFT_TOL * loaded normal force``).  These are ordinary
load steps.

``open``: the gripper's nodal forces on the upper face ``F_u`` (n_upper, 3), N,
measured when the release begins, are ramped down together, ``(1 - j / steps)
F_u`` at release step ``j``, with the upper face free; then settle steps
(``Command()``) follow until the regularising spring force of
:mod:`fe_contact.loads` is below ``settle_tol`` times the weight.  With
every upper-face dof free, the block's rigid modes are held by contact and
friction alone; the springs anchored at the last converged configuration
keep ``K`` positive definite for the flexibility matrix and vanish at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .elasticity import internal_force
from .loads import Loading
from .measure import measure
from .model import Command, Model, State, StepReport

MODES = ("lift", "open")
LIFT_TOL = 1e-9
"""Upper-face push, relative to the loaded normal force, below which the plate carries no load."""


@dataclass(frozen=True)
class Release:
    """How the gripper lets go after the last load step.

    Parameters
    ----------
    mode : {"lift", "open"}
    steps : int
        Increments of the release (>= 1).
    settle_tol : float
        ``open``: settle until the regularising spring force (norm over the
        dofs) is at most this fraction of the weight.
    max_steps : int
        Limit on the release's steps in all (ramp, extra lift, settle).
    """

    mode: str
    steps: int
    settle_tol: float = 1e-10
    max_steps: int = 200

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("steps", "max_steps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if not 0 < self.settle_tol < 1:
            raise ValueError(f"settle_tol must be in (0, 1), got {self.settle_tol}")


class ReleaseSchedule:
    """The commands of a release, each chosen after the previous step's report.

    ``next_command(state, report)`` returns the next :class:`Command`, or None
    when the block is released (or ``max_steps`` were taken); ``report`` is
    the last step's (None before the first release step).
    """

    def __init__(self, model: Model, release: Release, state: State, loaded: StepReport | None = None):
        if release.mode == "open" and model.material.density <= 0:
            raise ValueError("an open release needs a block with weight (material density > 0)")
        self.release = release
        self.weight = model.weight
        self.depth = max(0.0, -float(state.upper_translation[2]))
        self.loaded_normal = abs(loaded.normal_force) if loaded is not None else 0.0
        self.taken = 0

    def next_command(self, state: State, report: StepReport | None) -> Command | None:
        rel, j = self.release, self.taken
        if j >= rel.max_steps or (report is not None and not report.converged):
            return None
        if rel.mode == "lift":
            command = self._lift(j, report)
        elif j < rel.steps:
            command = Command(open=1.0 / rel.steps)
        else:
            command = None if report.regularisation_force <= rel.settle_tol * self.weight else Command()
        self.taken += command is not None
        return command

    def _lift(self, j: int, report: StepReport | None) -> Command | None:
        dz = self.depth / self.release.steps
        if j < self.release.steps:
            return Command(dz=dz) if dz > 0 else None
        pushing = report is not None and report.upper_force[2] < -LIFT_TOL * self.loaded_normal
        return Command(dz=dz) if pushing and dz > 0 else None


def run_release(model: Model, state: State, release: Release, step, loaded: StepReport | None = None):
    """Step ``model`` from ``state`` through ``release`` with ``step`` (``fe_contact.step``).

    Returns the final state and the reports of the release steps.
    """
    schedule = ReleaseSchedule(model, release, state, loaded)
    reports: list[StepReport] = []
    while (command := schedule.next_command(state, reports[-1] if reports else None)) is not None:
        state, report = step(model, state, command, consume=True)
        reports.append(report)
    return state, reports


def gripper_load(model: Model, state: State) -> np.ndarray:
    """Nodal forces (n_upper, 3), N, the gripper applies on the upper face in
    ``state``: the upper-face rows of ``f_int - f_body`` (the contact acts on
    the lower face only)."""
    f_int, _ = internal_force(model.geometry, model.mesh.elements, state.displacement, model.material)
    if model.body_force is not None:
        f_int = f_int - model.body_force
    return f_int.reshape(-1, 3)[model.mesh.upper]


def open_loading(model: Model, state: State, grip: float, upper_load: np.ndarray) -> Loading:
    """Applied loads of an open-release step to ``grip``: weight, the
    gripper's remaining load, and the regularising springs anchored at
    ``state`` (:mod:`fe_contact.loads`)."""
    external = np.zeros((model.mesh.n_nodes, 3))
    external[model.mesh.upper] = grip * upper_load
    external = external.ravel()
    if model.body_force is not None:
        external += model.body_force
    beta = model.options.release_stiffness
    k = np.zeros(model.mesh.n_nodes)
    k[model.mesh.lower] = beta * model.shear_stiffness * model.lower_area / model.lower_area.sum()
    return Loading(external=external, spring=np.repeat(k, 3), anchor=state.displacement.ravel().copy(),
                   diagonal=model.diagonal, tension_only_geometric=True)


def open_step(model: Model, state: State, command: Command, t0: float, local_problem_hook=None,
              consume: bool = False) -> tuple[State, StepReport]:
    """One step of an open release (see the module docstring); ``command``
    gives the fraction of the load released (``open``) and moves nothing."""
    from .newton import equilibrium
    from .step import next_state

    if command.moves:
        raise ValueError("the gripper has let go of the upper face: a command can no longer move it")
    upper_load = state.upper_load if state.upper_load is not None else gripper_load(model, state)
    grip = state.grip - command.open
    grip = 0.0 if grip <= 1e-12 else grip
    released = model.released()
    loading = open_loading(model, state, grip, upper_load)
    U = np.array(state.displacement, dtype=float)
    eq = equilibrium(released, state, U, local_problem_hook, consume, loading)
    extra = {"upper_force": grip * upper_load.sum(axis=0), "grip": grip}
    report = measure(released, state, command, eq, t0, loading, extra)
    if not report.converged:
        return state, report
    return next_state(state, eq, state.upper_translation, state.upper_rotation, report, plate=state.plate,
                      grip=grip, upper_load=upper_load), report

