"""A small arm for the Drake example: five revolute joints held by a PD controller
(Drake's ``PidController``) and a massless gripper welded to the last link at the
joint ``wrist``, in a continuous-time ``MultibodyPlant``.

Our own URDF: Drake's arm models (``package://drake_models/iiwa_description/...``) are
not in the pydrake wheel but downloaded on first use, and CI reaches only package
registries.  The gripper is massless so that the wrist's reaction is the force the
block applies on the gripper, whatever the arm's acceleration (as a wrist force sensor
between the arm and a massless hand reads: docs/conventions.md).  The plant is
continuous, so that the reaction port and the body's pose belong to the same state: a
discrete plant (``time_step > 0``, Drake 1.51) reports the reaction in the joint frame of
the configuration at the start of its last step (rotated with the current pose it was
0.37 N off on this arm after 5 ms; turned with the pose at the step's start, it is the
applied force to rounding).
"""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.controllers import PidController
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from ..planning.push_model import PushModel
from .system import FePushSystem


def _link(name: str, mass: float, length: float) -> str:
    i = mass * length ** 2 / 12.0 + 1e-4
    return (f'<link name="{name}"><inertial><origin xyz="0 0 {length / 2}"/><mass value="{mass}"/>'
            f'<inertia ixx="{i}" iyy="{i}" izz="1e-3" ixy="0" ixz="0" iyz="0"/></inertial></link>')


def _joint(name: str, parent: str, child: str, axis: str, xyz: str) -> str:
    return (f'<joint name="{name}" type="continuous"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/></joint>'
            f'<transmission type="SimpleTransmission"><joint name="{name}"/>'
            f'<actuator name="{name}_motor"/></transmission>')


_JOINTS = (("joint1", "base", "link1", "0 0 1", "0 0 0.1"), ("joint2", "link1", "link2", "0 1 0", "0 0 0.1"),
           ("joint3", "link2", "link3", "0 1 0", "0 0 0.4"), ("joint4", "link3", "link4", "0 1 0", "0 0 0.4"),
           ("joint5", "link4", "link5", "0 0 1", "0 0 0.1"))

ARM_URDF = ('<?xml version="1.0"?><robot name="push_arm">' + _link("base", 5.0, 0.1)
            + "".join(_link(f"link{k}", 2.0 if k < 4 else 0.5, 0.4 if k in (2, 3) else 0.1) for k in range(1, 6))
            + "".join(_joint(*j) for j in _JOINTS)
            + '<link name="gripper"/>'  # massless: the wrist reads the block's force
            + '<joint name="wrist" type="fixed"><parent link="link5"/><child link="gripper"/>'
              '<origin xyz="0 0 0.05"/></joint></robot>')
"""The arm's URDF: base welded to the world, joints ``joint1`` .. ``joint5``, the
gripper body ``gripper`` at the fixed joint ``wrist`` (its origin is the plate's centre)."""

Q0 = np.array([0.0, 1.2, 1.4, 0.55, 0.0])
"""rad: the held configuration, the gripper pointing down about 0.55 m from the base."""


def arm_diagram(push: PushModel, period: float, q0=Q0, gains=(5000.0, 100.0)):
    """A ``Diagram``: the arm's continuous ``MultibodyPlant``, its joints held at ``q0``
    by a PD controller of gains ``(p, d)`` (N m/rad, N m s/rad; no gravity
    compensation, the arm sags by a few mrad), and an :class:`FePushSystem` whose
    ``spatial_forces`` drive the plant's applied spatial force input; the FE frame is
    placed with the plate's centre at the gripper's origin at ``q0``.  The diagram's
    input ``gripper_command`` is the system's.

    Returns
    -------
    diagram, plant, fe : Diagram, MultibodyPlant, FePushSystem
    """
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    arm = Parser(plant).AddModelsFromString(ARM_URDF, "urdf")[0]
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", arm))
    plant.Finalize()
    q0 = np.asarray(q0, float)
    plant.SetDefaultPositions(arm, q0)
    gripper = plant.GetBodyByName("gripper", arm)
    X_WG = plant.EvalBodyPoseInWorld(plant.CreateDefaultContext(), gripper)
    height = push.model.mesh.size[2] + push.pressed.state.upper_translation[2]
    X_WF = RigidTransform(RollPitchYaw(0.0, 0.0, 0.0), X_WG.translation() - [0.0, 0.0, height])
    fe = builder.AddSystem(FePushSystem(push, gripper.index(), period, X_WF))
    builder.Connect(fe.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port())
    n = len(q0)
    pd = builder.AddSystem(PidController(np.full(n, gains[0]), np.zeros(n), np.full(n, gains[1])))
    desired = builder.AddSystem(ConstantVectorSource(np.concatenate([q0, np.zeros(n)])))
    builder.Connect(plant.get_state_output_port(arm), pd.get_input_port_estimated_state())
    builder.Connect(desired.get_output_port(), pd.get_input_port_desired_state())
    builder.Connect(pd.get_output_port_control(), plant.get_actuation_input_port(arm))
    builder.ExportInput(fe.get_input_port(0), "gripper_command")
    return builder.Build(), plant, fe
