"""``simulate``: a scenario's load steps (then its ``[release]``, if any) through the
driver, with the run's files.

Outputs in ``out_dir``: ``summary.json`` (:class:`~pushplan.run.summary.RunSummary`,
rewritten after every step so a failing run keeps its finished steps),
``fields.npz`` (see :mod:`pushplan.run.observers`) and ``recording.rrd``
(:mod:`pushplan.outputs.recording`), unless ``recording=False``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from fe_contact import Model, State

from ..config.commands import commands_to_list
from ..config.scenario import Scenario
from .driver import Run, drive
from .observers import FclibExport, FieldsFile, Progress, RecordingFile, SummaryFile

RECORDING_FILE = "recording.rrd"


def resolved_scenario(scenario: Scenario, commands) -> dict:
    """The scenario as run: its tables with ``load`` replaced by the commands applied."""
    return {**scenario.to_dict(), "load": commands_to_list(commands)}


def simulate(
    scenario: Scenario,
    out_dir=None,
    commands=None,
    model: Model | None = None,
    state: State | None = None,
    progress: bool = False,
    recording: bool | str | os.PathLike = True,
    export_fclib: str | os.PathLike | None = None,
    observers=(),
) -> Run:
    """Run the scenario's load steps (or ``commands``) and, with ``out_dir``, write
    ``summary.json``, ``fields.npz`` and ``recording.rrd`` there.

    Parameters
    ----------
    scenario : Scenario
    out_dir : path, optional
        Existing writable folder.
    commands : sequence of fe_contact.Command, optional
        Replace the scenario's ``[[load]]`` entries.
    model, state : optional
        Reuse a model / start from a state (defaults: ``scenario.model()``, rest).
    progress : bool
        Progress on stderr.
    recording : bool or path
        ``True``: ``out_dir/recording.rrd`` when ``out_dir`` is given; a path: the
        rerun recording there; ``False``: none.
    export_fclib : path, optional
        Existing folder: the last local contact problem of every step is written
        there as ``step_NNN.hdf5`` (FCLIB, :func:`fe_contact.io.fclib.write_local_problem`).
    observers : sequence
        More observers of the run (see :mod:`pushplan.run.driver`).
    """
    model = model or scenario.model()
    commands = tuple(scenario.commands if commands is None else commands)
    resolved = resolved_scenario(scenario, commands)
    out = Path(out_dir) if out_dir is not None else None
    watchers = list(observers)
    if progress:
        watchers.append(Progress(len(commands), sys.stderr))
    if export_fclib is not None:
        watchers.append(FclibExport(export_fclib, scenario.name))
    if out is not None:
        watchers += [SummaryFile(out / "summary.json"), FieldsFile(out / "fields.npz")]
    if recording is not False and (recording is not True or out is not None):
        from ..outputs.recording import Recorder

        path = out / RECORDING_FILE if recording is True else Path(recording)
        watchers.append(RecordingFile(Recorder(path, scenario.name, model.mesh, scenario=resolved)))
    return drive(model, commands, state, scenario=resolved, observers=watchers, release=scenario.release)
