"""Transitional: registers the commands of pushplan.studies.paper."""

from ..studies.paper import register  # noqa: F401
