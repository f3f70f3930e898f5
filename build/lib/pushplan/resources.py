"""Files shipped inside the package (so that a plain ``pip install`` has them):
the scenarios of ``scenarios/`` (the top-level ``scenarios`` folder of a checkout
is a link to ``pushplan/scenarios``)."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def scenario_path(name: str) -> Path:
    """Path of a shipped scenario file (``"paper_case3.toml"``)."""
    return Path(str(files("pushplan") / "scenarios" / name))
