"""Transitional: registers the commands of pushplan.studies.sweep."""

from ..studies.sweep import register  # noqa: F401
