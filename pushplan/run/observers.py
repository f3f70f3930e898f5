"""Observers of :func:`pushplan.run.driver.drive` that write a run's files.

``SummaryFile``     ``summary.json``, rewritten atomically after every step.
``FieldsFile``      ``fields.npz``: reference mesh and per-step nodal fields.
``RecordingFile``   ``recording.rrd`` (rerun), see :mod:`pushplan.outputs.recording`.
``FclibExport``     each step's last local contact problem as FCLIB HDF5.
``Progress``        a progress bar on a terminal, one line per step otherwise.

``fields.npz`` holds the reference mesh (``nodes`` (n,3) m, ``elements`` (e,8),
``lower``, ``upper`` node ids, ``lower_area`` (n_lower,) m^2) and per-step nodal
fields stacked on a leading step axis: ``displacement`` (s,n,3) m, ``reaction_local``
(s,n_lower,3) N as (n, t_x, t_y), ``reaction_world`` (s,n_lower,3) N, ``pressure``
(s,n_lower) Pa, ``slip`` (s,n_lower) m (norm of the total tangential displacement),
``slip_path`` (s,n_lower) m, ``slip_increment`` (s,n_lower,2) m, ``gap`` (s,n_lower) m,
``node_status`` (s,n_lower) 0 stick / 1 slip / 2 separated; the pad's nodes ``pad_nodes``
(n_pad,) (the upper-face nodes under its footprint, all of ``upper`` without one) and
``pad_force`` (s,n_pad,3) N, world: the force the pad applies on each of them (a bonded
pad's drive reaction, a frictional pad's contact force; its sum is the step's
``upper_force``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fe_contact import StepReport

from ..outputs.atomic import atomic_write_json, atomic_write_npz

FIELD_NAMES = (
    "displacement", "reaction_local", "reaction_world", "pressure", "slip",
    "slip_path", "slip_increment", "gap", "node_status", "pad_force",
)


class SummaryFile:
    def __init__(self, path):
        self.path = Path(path)

    def step(self, run, report: StepReport) -> None:
        atomic_write_json(self.path, run.summary.to_dict())

    def finish(self, run) -> None:
        atomic_write_json(self.path, run.summary.to_dict())


class FieldsFile:
    def __init__(self, path):
        self.path = Path(path)
        self.fields = {name: [] for name in FIELD_NAMES}

    def step(self, run, report: StepReport) -> None:
        if report.converged:
            for name in FIELD_NAMES:
                self.fields[name].append(getattr(report, name))

    def finish(self, run) -> None:
        mesh = run.model.mesh
        arrays = {name: np.asarray(v) for name, v in self.fields.items() if v}
        atomic_write_npz(self.path, nodes=mesh.nodes, elements=mesh.elements, lower=mesh.lower,
                         upper=mesh.upper, lower_area=run.model.lower_area, pad_nodes=run.model.held_nodes, **arrays)


class RecordingFile:
    """Logs every step into a :class:`~pushplan.outputs.recording.Recorder`, closed with the run."""

    def __init__(self, recorder):
        self.recorder = recorder

    def step(self, run, report: StepReport) -> None:
        self.recorder.log_step(report, run.summary.steps[-1] if report.converged else None)

    def finish(self, run) -> None:
        if run.summary.rest is not None:
            self.recorder.log_rest(run.summary.rest)
        for warning in run.summary.warnings:
            self.recorder.log_warning(warning)

    def close(self, run) -> None:
        self.recorder.close()


class FclibExport:
    """Writes the last local problem of every step to ``folder/step_NNN.hdf5``."""

    def __init__(self, folder, run_name: str):
        self.folder = Path(folder)
        self.run_name = run_name
        self._last = None

    def local_problem(self, W, q, solution) -> None:
        self._last = (W, q, solution)

    def step(self, run, report: StepReport) -> None:
        from fe_contact import write_local_problem

        if self._last is None:
            return
        W, q, sol = self._last
        self._last = None
        model, friction, k = run.model, run.model.friction, report.step_index
        contacts = model.contacts  # the floor's, then a frictional pad's (each its own cone)
        angles = [friction.angle] + ([model.pad.angle] if model.pad is not None else [])
        write_local_problem(
            self.folder / f"step_{k:03d}.hdf5", W, q, contacts.mu_x, contacts.mu_y,
            angle=np.asarray(angles)[contacts.body],
            title=f"pushplan {self.run_name} step {k}",
            description=(
                f"Last local contact problem of load step {k} ({report.status.value}) of scenario "
                f"{self.run_name}: {model.n_contacts} lower-face nodes of a hex8 block on a plane, elliptic "
                f"friction mu_x={friction.mu_x}, mu_y={friction.mu_y}. W and q are divided by the mean "
                "diagonal compliance of W (so q, u are in N like r); r, u are pushplan's solution."
            ),
            r=sol.r, u=sol.u,
        )


class Progress:
    """A progress bar on ``stream`` when it is a terminal; a plain line per step otherwise."""

    WIDTH = 24

    def __init__(self, n_steps: int, stream):
        self.n = n_steps
        self.stream = stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def step(self, run, report: StepReport) -> None:
        i = len(run.reports)
        done = min(int(self.WIDTH * i / max(self.n, 1)), self.WIDTH)
        # a release's steps come after the n load steps, as many as its step control takes
        where = f"step {i}/{self.n}" if i <= self.n else f"release step {i - self.n}"
        text = (f"{where}  newton {report.newton_iterations}  contact {report.contact_iterations}"
                f"  {report.wall_time:.2f}s")
        if not self.tty:
            self.stream.write(text + "\n")
        else:
            self.stream.write(f"\r[{'#' * done}{'.' * (self.WIDTH - done)}] {text}")
            if i == self.n or not report.converged:
                self.stream.write("\n")
        self.stream.flush()
