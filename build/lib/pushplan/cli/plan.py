"""Transitional: registers the commands of pushplan.planning.planner."""

from ..planning.planner import register  # noqa: F401
