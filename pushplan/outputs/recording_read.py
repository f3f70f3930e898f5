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
from ..limits import MAX_STEPS


@dataclass(frozen=True)
class RecordedRun:
    """What ``pushplan replay`` needs from a recording."""

    run_name: str
    scenario: dict | None
    steps: np.ndarray  # (n,) step indices
    commands: tuple[Command, ...]
    lower_centroid: np.ndarray  # (n, 3) m, cumulative displacement


def _column(batch, name: str, path) -> list:
    if name not in batch.schema.names:
        raise InputError(f"{path} is not a pushplan recording: column {name} missing")
    return batch.column(name).to_pylist()


def _info(batch, path) -> dict:
    """The ``run/info`` document: a JSON object with ``run_name`` (str) and ``scenario``
    (a table or null)."""
    try:
        info = json.loads(_column(batch, "TextDocument:text", path)[-1][0])
    except (ValueError, TypeError, IndexError, RecursionError) as exc:  # not JSON, an empty or null text
        raise InputError(f"{path}: run/info is not a JSON document ({' '.join(str(exc).split())[:100]})") from None
    if not isinstance(info, dict) or not isinstance(info.get("run_name"), str) \
            or not isinstance(info.get("scenario", None), (dict, type(None))):
        raise InputError(f"{path}: run/info must be a JSON object with run_name (text) and scenario (a table), "
                         f"got {str(info)[:60]}")
    return info


def _commands(rows, path) -> tuple:
    if len(rows) > MAX_STEPS:
        raise InputError(f"{path}: {len(rows)} recorded steps, more than {MAX_STEPS}")
    try:
        return tuple(command_from_dict(dict(zip(COMMAND_KEYS, (v[0] for v in row[1:5]), strict=True)), f"{path} step {row[0]}")
                     for row in rows)
    except (TypeError, IndexError) as exc:
        raise InputError(f"{path}: a recorded step is not a command ({exc})") from None


def read_recording(path) -> RecordedRun:
    """Read the run description and per-step commands of a recording.

    Raises
    ------
    InputError
        Missing or unreadable file, or an ``.rrd`` not written by ``Recorder``
        (``run/info`` not a JSON object with ``run_name``, steps that are not commands).
    """
    from rerun.chunk import RrdReader

    path = Path(path)
    if not path.is_file():
        raise InputError(f"recording not found: {path}")
    try:
        chunks = RrdReader(path).stream().filter(content="/run/**").to_chunks()
    except (RuntimeError, OSError) as exc:  # rerun's bindings: a file unreadable or not an RRD
        raise InputError(f"cannot read recording {path}: {' '.join(str(exc).split())[:200]}") from None
    info, rows = None, []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/run/info":
            info = _info(batch, path)
        elif chunk.entity_path == "/run/step":
            names = ("step", "dx", "dy", "dz", "dtheta_deg", "lower_centroid")
            rows.extend(zip(*(_column(batch, n, path) for n in names), strict=True))
    if info is None:
        raise InputError(f"{path} is not a pushplan recording (no run/info)")
    try:
        rows.sort(key=lambda r: r[0])
        lower = np.array([r[5] for r in rows], dtype=float).reshape(-1, 3)
        steps = np.array([r[0] for r in rows], dtype=np.int64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: recorded steps are malformed ({' '.join(str(exc).split())[:100]})") from None
    return RecordedRun(run_name=info["run_name"], scenario=info.get("scenario"), steps=steps,
                       commands=_commands(rows, path), lower_centroid=lower)
