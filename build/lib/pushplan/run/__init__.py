"""Running the FE model: the one driver loop, its observers, typed summaries and
``simulate``.  Imports nothing from ``planning``, ``mujoco``, ``studies`` or ``cli``."""

from .driver import Run, drive
from .simulate import simulate
from .summary import Failure, RunStatus, RunSummary, StepSummary

__all__ = ["Failure", "Run", "RunStatus", "RunSummary", "StepSummary", "drive", "simulate"]
