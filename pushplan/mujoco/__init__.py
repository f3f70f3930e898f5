"""MuJoCo at the edge of ``pushplan``: MJCF scene import (:mod:`.scene`), gripper
trajectories and their export (:mod:`.trajectory`), the FE block coupled into a
user's MuJoCo loop (:mod:`.coupling`), an arm controller that reaches its command
under the block's load (:mod:`.arm`), a headless co-simulation (:mod:`.cosim`) and
the comparison with MuJoCo's rigid and flex models (:mod:`.compare`).  ``mujoco`` itself is imported inside functions only; its settings
table is :mod:`pushplan.config.mujoco`."""

from ..config.mujoco import BridgeSettings, bridge_settings
from .arm import PositionController
from .compare import MODEL_NOTES, Comparison, ModelRun, compare
from .cosim import CosimPeriod, CosimRecord, run_cosimulation
from .coupling import KINEMATIC_ARMATURE, USERDATA_LAYOUT, CoSimulation, attach
from .flex import flex_mjcf
from .records import ComparisonStep
from .scene import MjcfScene, open_scene, scene_from_mjcf
from .trajectory import CSV_COLUMNS, GripperTrajectory, export_plan, gripper_trajectory

__all__ = [
    "CSV_COLUMNS", "KINEMATIC_ARMATURE", "MODEL_NOTES", "USERDATA_LAYOUT", "BridgeSettings", "CoSimulation",
    "Comparison", "ComparisonStep", "CosimPeriod", "CosimRecord", "GripperTrajectory", "MjcfScene", "ModelRun", "PositionController", "attach", "bridge_settings", "compare", "export_plan", "flex_mjcf",
    "gripper_trajectory", "open_scene", "run_cosimulation", "scene_from_mjcf",
]
