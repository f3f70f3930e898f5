"""MuJoCo at the edge of ``pushplan``: MJCF scene import (:mod:`.scene`), gripper
trajectories and their export (:mod:`.trajectory`), the FE block co-simulated in a
MuJoCo loop (:mod:`.cosim`) and the comparison with MuJoCo's rigid and flex models
(:mod:`.compare`).  ``mujoco`` itself is imported inside functions only; its settings
table is :mod:`pushplan.config.mujoco`."""

from ..config.mujoco import BridgeSettings, bridge_settings
from .compare import MODEL_NOTES, Comparison, ModelRun, compare
from .cosim import USERDATA_LAYOUT, CoSimulation, CosimPeriod, CosimRecord, run_cosimulation
from .flex import flex_mjcf
from .records import ComparisonStep
from .scene import MjcfScene, open_scene, scene_from_mjcf
from .trajectory import CSV_COLUMNS, GripperTrajectory, export_plan, gripper_trajectory

__all__ = [
    "CSV_COLUMNS", "MODEL_NOTES", "USERDATA_LAYOUT", "BridgeSettings", "CoSimulation", "Comparison",
    "ComparisonStep", "CosimPeriod", "CosimRecord",
    "GripperTrajectory", "MjcfScene", "ModelRun", "bridge_settings", "compare", "export_plan", "flex_mjcf",
    "gripper_trajectory", "open_scene", "run_cosimulation", "scene_from_mjcf",
]
