"""Transitional: registers the commands of pushplan.mujoco.bridge."""

from ..mujoco.bridge import register  # noqa: F401
