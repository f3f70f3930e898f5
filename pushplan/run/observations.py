"""Observation files of a run (:mod:`pushplan.config.observations`): what a robot
would have observed had the FE model been the real block.

The observed force is ``upper_force`` of the step summary: the force the gripper
applies on the block, what a wrist force sensor between the arm and the hand reads
(docs/conventions.md, the one sign convention of forces).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..config.observations import OBSERVED_COLUMNS, Observations, encode_observations
from ..outputs.atomic import atomic_write_bytes
from .summary import StepSummary


def observed_values(steps) -> dict:
    """Every observed column of :data:`OBSERVED_COLUMNS` from step summaries, (K,) arrays."""
    steps = list(steps)
    lower = np.array([s.lower_centroid for s in steps], float).reshape(-1, 3)
    force = np.array([s.upper_force for s in steps], float).reshape(-1, 3)
    yaw = np.array([math.degrees(s.lower_yaw) for s in steps], float)
    columns = (lower[:, 0], lower[:, 1], yaw, force[:, 0], force[:, 1], force[:, 2])
    return dict(zip(OBSERVED_COLUMNS, columns, strict=True))


def observations_from_steps(steps: list[StepSummary], columns=OBSERVED_COLUMNS) -> Observations:
    """The observations of converged steps (``columns`` of them)."""
    values = observed_values(steps)
    return Observations(tuple(s.command for s in steps), {k: values[k] for k in columns})


class ObservationsFile:
    """Observer writing the run's converged steps as an observation file (CSV or JSON
    by the suffix of ``path``) when the run ends."""

    def __init__(self, path):
        self.path = Path(path)

    def step(self, run, report) -> None:
        pass

    def finish(self, run) -> None:
        if run.summary.steps:
            obs = observations_from_steps(run.summary.steps)
            atomic_write_bytes(self.path, encode_observations(obs, self.path))
