"""The FE push model as a Drake ``LeafSystem``: a gripper command in, the block's pose
and the reaction on the gripper out, for a ``Diagram`` with a robot ``MultibodyPlant``.

The system holds the FE state (displacements, contact forces, slip paths: path
dependent) in its abstract state and advances it by one FE step
(:meth:`PushModel.step_report`) at each periodic update whose command differs from
the held gripper pose; between updates its outputs are those of the held state.
A command the FE model refuses (not finite, a move longer than the block) raises
:class:`~pushplan.errors.InputError` naming it; a step that fails, ``PlanningError``.

Wrench on the block about the plate's centre ``c`` (the upper face's current centre),
FE frame: the force is the step's ``upper_force`` (what pushplan reports, N); the
moment follows from the block's balance of moments (the internal forces carry none,
total Lagrangian hex8),

    M = - sum_i (x_i - c) x r_i  -  sum_n (x_n - c) x b_n          (N m)

``r_i`` the floor's contact force on lower-face node ``i`` (world), ``b_n`` the nodal
self-weight, ``x`` current positions: exact to the step's equilibrium tolerance (its
``M_z`` is the reported ``gripper_force[2]``, tests/test_drake.py).  Drake applies
forces to the body named in the output, so the gripper receives ``-(M, F)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.systems.framework import LeafSystem

from fe_contact import State, StepReport

from ..errors import InputError
from ..planning.push_model import PushModel


def block_wrench(model, report: StepReport) -> np.ndarray:
    """Wrench ``(M_x, M_y, M_z, F_x, F_y, F_z)`` (6,), N m and N, that the gripper
    applies on the block after ``report``'s step, about the plate's centre, FE frame
    (module docstring)."""
    U = report.displacement
    x = model.mesh.nodes + U
    c = x[model.held_nodes].mean(axis=0)
    lower = model.mesh.lower
    moment = -np.cross(x[lower] - c, report.reaction_world).sum(axis=0)
    if model.body_force is not None:
        moment -= np.cross(x - c, model.body_force.reshape(-1, 3)).sum(axis=0)
    return np.concatenate([moment, report.upper_force])


@dataclass(frozen=True)
class Held:
    """What the system carries between updates: the FE state, the gripper's in-plane
    pose ``(x, y, theta)`` it was driven to (m, m, rad, FE frame), the lower face's pose
    ``(x, y, yaw)`` and the wrench on the block (:func:`block_wrench`), and the
    number of FE steps taken."""

    state: State
    gripper: np.ndarray
    pose: np.ndarray
    wrench: np.ndarray
    steps: int = 0

    def __deepcopy__(self, memo) -> "Held":
        """Itself: Drake copies abstract state by ``deepcopy`` (at every unrestricted update
        and context clone); a step never changes a held state but makes a new one
        (``drive`` never mutates its start state), so contexts may share it."""
        return self


class FePushSystem(LeafSystem):
    """A pressed FE block as a Drake system (module docstring).

    Parameters
    ----------
    push : PushModel
        The FE model and its press; the system starts from ``push.pressed``.
    body_index : BodyIndex
        The plant body that holds the gripper: its origin ``Bo`` is the plate's
        centre (the force is applied there).
    period : float
        s, between updates (each costs one FE step when the command moved).
    X_WF : RigidTransform, optional
        The FE frame in Drake's world (default: the same frame).  The FE frame has
        its origin at the undeformed block's lower-face centre, z up.

    Ports
    -----
    input ``gripper_command`` (3): the gripper's in-plane pose ``(x, y, theta)``, m, m,
        rad, FE frame, from the undeformed block (the press's in-plane part included;
        PushModel's commands are its increments).
    output ``block_pose`` (3): the lower face's ``(x, y, yaw)`` (PushModel's poses).
    output ``block_transform``: ``RigidTransform`` of the lower face's centre in Drake's world.
    output ``wrench_on_block`` (6): ``(M, F)`` the gripper applies on the block, N m and N,
        Drake's world frame, about the plate's centre (pushplan's convention).
    output ``spatial_forces``: ``[ExternallyAppliedSpatialForce]`` on ``body_index`` at
        ``Bo``: the reaction ``-(M, F)``, world frame, for
        ``MultibodyPlant.get_applied_spatial_force_input_port()``.
    """

    def __init__(self, push: PushModel, body_index, period: float, X_WF: RigidTransform | None = None):
        super().__init__()
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period!r}")
        self.push, self.body_index = push, body_index
        self.X_WF = RigidTransform() if X_WF is None else X_WF
        pressed = push.pressed
        self.initial = self._held(pressed.state, pressed.reports[-1], 0)
        self._index = self.DeclareAbstractState(AbstractValue.Make(self.initial))
        held = {self.abstract_state_ticket(self._index)}
        self.DeclareVectorInputPort("gripper_command", 3)
        self.DeclareVectorOutputPort("block_pose", 3, self._pose, prerequisites_of_calc=held)
        self.DeclareAbstractOutputPort("block_transform", lambda: AbstractValue.Make(RigidTransform()),
                                       self._transform, prerequisites_of_calc=held)
        self.DeclareVectorOutputPort("wrench_on_block", 6, self._wrench, prerequisites_of_calc=held)
        self.DeclareAbstractOutputPort("spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
                                       self._forces, prerequisites_of_calc=held)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)

    def _held(self, state: State, report: StepReport, steps: int) -> Held:
        gripper = np.array([*state.upper_translation[:2], state.upper_rotation])
        pose = np.array([*report.lower_centroid[:2], report.lower_yaw])
        return Held(state, gripper, pose, block_wrench(self.push.model, report), steps)

    def held(self, context) -> Held:
        """The :class:`Held` FE state in this system's ``context``."""
        return context.get_abstract_state(self._index).get_value()

    def _update(self, context, state) -> None:
        held = self.held(context)
        command = np.asarray(self.get_input_port(0).Eval(context), float)
        increment = command - held.gripper
        if not increment.any():
            return
        try:
            fe_state, report = self.push.step_report(held.state, increment)
        except InputError as e:
            raise InputError(f"gripper_command {command.tolist()} at t = {context.get_time():g} s, "
                             f"a move of {increment.tolist()} from the held pose: {e}") from None
        state.get_mutable_abstract_state(self._index).set_value(self._held(fe_state, report, held.steps + 1))

    def _pose(self, context, output) -> None:
        output.SetFromVector(self.held(context).pose)

    def _transform(self, context, output) -> None:
        x, y, yaw = self.held(context).pose
        X_FL = RigidTransform(RollPitchYaw(0.0, 0.0, yaw), [x, y, 0.0])
        output.set_value(self.X_WF @ X_FL)

    def _world_wrench(self, context) -> np.ndarray:
        R = self.X_WF.rotation().matrix()
        w = self.held(context).wrench
        return np.concatenate([R @ w[:3], R @ w[3:]])

    def _wrench(self, context, output) -> None:
        output.SetFromVector(self._world_wrench(context))

    def _forces(self, context, output) -> None:
        w = self._world_wrench(context)
        force = ExternallyAppliedSpatialForce()
        force.body_index = self.body_index
        force.p_BoBq_B = np.zeros(3)
        force.F_Bq_W = SpatialForce(-w[:3], -w[3:])
        output.set_value([force])
