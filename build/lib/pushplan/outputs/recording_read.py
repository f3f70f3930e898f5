"""Reading back what :class:`pushplan.outputs.recording.Recorder` wrote: the run
description and the per-step commands and lower-face trajectory (for ``replay``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fe_contact import Command

from ..config.commands import COMMAND_KEYS, command_from_dict
from ..errors import InputError


@dataclass(frozen=True)
class RecordedRun:
    """What ``pushplan replay`` needs from a recording."""

    run_name: str
    scenario: dict | None
    steps: np.ndarray  # (n,) step indices
    commands: tuple[Command, ...]
    lower_centroid: np.ndarray  # (n, 3) m, cumulative displacement


def _column(batch, name: str) -> list:
    if name not in batch.schema.names:
        raise InputError(f"column {name} missing")
    return batch.column(name).to_pylist()


def read_recording(path) -> RecordedRun:
    """Read the run description and per-step commands of a recording.

    Raises
    ------
    InputError
        Missing or unreadable file, or an ``.rrd`` not written by ``Recorder``.
    """
    from rerun.chunk import RrdReader

    path = Path(path)
    if not path.is_file():
        raise InputError(f"recording not found: {path}")
    try:
        chunks = RrdReader(path).stream().filter(content="/run/**").to_chunks()
    except Exception as exc:  # the bindings raise assorted types for a corrupt file
        raise InputError(f"cannot read recording {path}: {exc}") from None
    info, rows = None, []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/run/info":
            info = json.loads(_column(batch, "TextDocument:text")[-1][0])
        elif chunk.entity_path == "/run/step":
            names = ("step", "dx", "dy", "dz", "dtheta_deg", "lower_centroid")
            rows.extend(zip(*(_column(batch, n) for n in names)))
    if info is None:
        raise InputError(f"{path} is not a pushplan recording (no run/info)")
    rows.sort(key=lambda r: r[0])
    commands = tuple(command_from_dict(dict(zip(COMMAND_KEYS, (v[0] for v in row[1:5]))), f"step {row[0]}")
                     for row in rows)
    return RecordedRun(
        run_name=info["run_name"],
        scenario=info["scenario"],
        steps=np.array([r[0] for r in rows], dtype=np.int64),
        commands=commands,
        lower_centroid=np.array([r[5] for r in rows], dtype=float).reshape(-1, 3),
    )
