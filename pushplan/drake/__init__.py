"""The FE push model in Drake (optional extra ``drake``: ``pip install 'pushplan[drake]'``).

``system``   :class:`FePushSystem`, a ``LeafSystem``: gripper command in; the block's
             pose and the reaction on the gripper (``ExternallyAppliedSpatialForce``) out
``arm``      a small 5-joint arm (our own URDF: Drake's arm models are downloaded at run
             time) and :func:`arm_diagram`, the system wired to its end body
``program``  the FE rollout as a ``MathematicalProgram`` constraint or cost with its
             exact gradient (AutoDiffXd), :func:`plan_to_target`

Contract (docs/plugins.md, "Drake"): SI units and radians; commands and poses are
:class:`~pushplan.planning.PushModel`'s; forces in Drake are Drake's (the force on
the body they are applied to), so the reaction on the gripper is the negative of the
force on the block that pushplan reports (docs/conventions.md).
"""

try:
    import pydrake  # noqa: F401
except ImportError:
    raise ImportError("pushplan.drake needs pydrake: pip install 'pushplan[drake]'") from None

from .arm import ARM_URDF, arm_diagram
from .program import DrakePlan, add_push_constraint, add_push_cost, plan_to_target
from .system import FePushSystem, block_wrench

__all__ = ["ARM_URDF", "DrakePlan", "FePushSystem", "add_push_constraint", "add_push_cost", "arm_diagram",
           "block_wrench", "plan_to_target"]
