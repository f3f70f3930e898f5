"""Run a scenario's load steps through ``fe_contact`` and write its outputs.

Outputs in ``DIR``:

``summary.json``
    ``scenario`` (resolved parameters), ``elapsed_s``, ``status`` (``"completed"``
    or ``"failed"``), ``failure`` (null or the failing step's status and message),
    and ``steps``: one object per finished load step (see :func:`step_summary`).
    Rewritten atomically after every step, so a failing run keeps its finished steps.
``recording.rrd``
    rerun recording of the run (see :mod:`pushplan.recording`), unless
    ``recording=False``.
``fields.npz``
    Reference mesh (``nodes`` (n,3) m, ``elements`` (e,8), ``lower``, ``upper`` node ids,
    ``lower_area`` (n_lower,) m^2) and per-step nodal fields stacked on a leading
    step axis: ``displacement`` (s,n,3) m, ``reaction_local`` (s,n_lower,3) N as
    (n, t_x, t_y), ``reaction_world`` (s,n_lower,3) N, ``pressure`` (s,n_lower) Pa,
    ``slip`` (s,n_lower) m (norm of the total tangential displacement), ``slip_path``
    (s,n_lower) m, ``slip_increment`` (s,n_lower,2) m, ``gap`` (s,n_lower) m,
    ``node_status`` (s,n_lower) 0 stick / 1 slip / 2 separated.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fe_contact import Command, Model, NodeStatus, State, StepReport, initial_state, step

from .io import atomic_write_json, atomic_write_npz
from .scenario import Scenario

FIELD_NAMES = (
    "displacement", "reaction_local", "reaction_world", "pressure", "slip",
    "slip_path", "slip_increment", "gap", "node_status",
)


def step_summary(report: StepReport) -> dict:
    """JSON-ready numbers of one step (SI units, angles in degrees)."""
    in_contact = report.node_status != NodeStatus.SEPARATED
    p = report.pressure[in_contact]
    return {
        "step": report.step_index,
        "command": {"dx": report.command.dx, "dy": report.command.dy, "dz": report.command.dz,
                    "dtheta_deg": math.degrees(report.command.dtheta)},
        "converged": report.converged,
        "status": report.status.value,
        "upper_centroid": report.upper_centroid,
        "lower_centroid": report.lower_centroid,
        "lower_yaw_deg": math.degrees(report.lower_yaw),
        "twist_deg": math.degrees(report.twist),
        "lag": report.lag,
        "max_slip": float(report.slip.max()),
        "pressure_max": float(p.max()) if p.size else 0.0,
        "pressure_min": float(p.min()) if p.size else 0.0,
        "normal_force": report.normal_force,
        "tangential_force": report.tangential_force,
        "upper_force": report.upper_force,
        "equilibrium_error": report.equilibrium_error,
        "n_stick": report.n_stick,
        "n_slip": report.n_slip,
        "n_separated": report.n_separated,
        "dissipation": report.dissipation,
        "newton_iterations": report.newton_iterations,
        "contact_iterations": report.contact_iterations,
        "newton_residual": report.newton_residual,
        "contact_residual": report.contact_residual,
        "min_det_f": report.min_det_f,
        "wall_time_s": report.wall_time,
    }


@dataclass
class SimulationResult:
    model: Model
    state: State
    reports: list[StepReport] = field(default_factory=list)
    summary: dict = field(default_factory=dict)

    @property
    def completed(self) -> bool:
        return self.summary.get("status") == "completed"


def _progress(i: int, n: int, report: StepReport, stream) -> None:
    width = 24
    done = int(width * i / max(n, 1))
    stream.write(
        f"\r[{'#' * done}{'.' * (width - done)}] step {i}/{n}  newton {report.newton_iterations}"
        f"  contact {report.contact_iterations}  {report.wall_time:.2f}s"
    )
    if i == n or not report.converged:
        stream.write("\n")
    stream.flush()


def _export_local_problem(folder: Path, scenario: Scenario, model: Model, rep: StepReport, W, q, sol) -> None:
    from fe_contact.fclib import write_local_problem

    friction = model.friction
    write_local_problem(
        folder / f"step_{rep.step_index:03d}.hdf5", W, q, friction.mu_x, friction.mu_y, angle=friction.angle,
        title=f"pushplan {scenario.name} step {rep.step_index}",
        description=(
            f"Last local contact problem of load step {rep.step_index} ({rep.status.value}) of scenario "
            f"{scenario.name}: {model.n_contacts} lower-face nodes of a hex8 block on a plane, elliptic "
            f"friction mu_x={friction.mu_x}, mu_y={friction.mu_y}. W and q are divided by the mean "
            "diagonal compliance of W (so q, u are in N like r); r, u are pushplan's solution."
        ),
        r=sol.r, u=sol.u,
    )


def simulate(
    scenario: Scenario,
    out_dir=None,
    commands=None,
    model: Model | None = None,
    state: State | None = None,
    progress: bool = False,
    recording: bool | str | os.PathLike = True,
    export_fclib: str | os.PathLike | None = None,
) -> SimulationResult:
    """Run the scenario's load steps (or ``commands``) and, with ``out_dir``, write
    ``summary.json`` and ``fields.npz`` there.

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
        Print a progress bar on stderr.
    recording : bool or path
        ``True``: write ``out_dir/recording.rrd`` when ``out_dir`` is given; a path:
        write the rerun recording there; ``False``: none.
    export_fclib : path, optional
        Existing folder: the last (converged) local contact problem of every
        step is written there as ``step_NNN.hdf5`` in FCLIB form (see
        :func:`fe_contact.fclib.write_local_problem`), for external solvers.
    """
    t0 = time.perf_counter()
    model = model or scenario.model()
    own_state = state is None  # then every state is ours and a refresh may free the previous tangent
    state = state or initial_state(model)
    commands = tuple(scenario.commands if commands is None else commands)
    for i, c in enumerate(commands):
        if not isinstance(c, Command):
            raise ValueError(f"commands[{i}] must be a fe_contact.Command, got {type(c).__name__}")
    resolved = scenario.to_dict()
    resolved["load"] = [
        {"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": math.degrees(c.dtheta)} for c in commands
    ]
    result = SimulationResult(model=model, state=state)
    summary = {"scenario": resolved, "elapsed_s": 0.0, "status": "running", "failure": None, "steps": []}
    fields = {name: [] for name in FIELD_NAMES}
    out = Path(out_dir) if out_dir is not None else None
    recorder = None
    if recording is not False and (recording is not True or out is not None):
        from .recording import RECORDING_FILE, Recorder

        path = out / RECORDING_FILE if recording is True else Path(recording)
        recorder = Recorder(path, scenario.name, model.mesh, scenario=resolved)
    try:
        for i, cmd in enumerate(commands, start=1):
            last_local: list = []  # the step's last local problem, for export_fclib

            def keep_last(W, q, sol):
                last_local[:] = [(W, q, sol)]

            try:
                state, rep = step(model, state, cmd, local_problem_hook=keep_last if export_fclib is not None else None,
                                  consume=own_state or i > 1)
            except (ValueError, ArithmeticError, RuntimeError) as exc:
                # a numerical breakdown the step did not turn into a status (singular
                # factorisation, ill-conditioned flexibility matrix) is still a failure
                summary["failure"] = {"step": state.step_index + 1, "status": "exception",
                                      "message": f"{type(exc).__name__}: {exc}"}
                summary["status"] = "failed"
                break
            result.reports.append(rep)
            if progress:
                _progress(i, len(commands), rep, sys.stderr)
            if export_fclib is not None and last_local:
                _export_local_problem(Path(export_fclib), scenario, model, rep, *last_local[0])
            if rep.converged:
                summary["steps"].append(step_summary(rep))
                for name in FIELD_NAMES:
                    fields[name].append(getattr(rep, name))
            else:
                summary["failure"] = {"step": rep.step_index, "status": rep.status.value, "message": rep.message}
            if recorder is not None:
                recorder.log_step(rep, summary["steps"][-1] if rep.converged else None)
            summary["status"] = "running" if rep.converged else "failed"
            summary["elapsed_s"] = time.perf_counter() - t0
            if out is not None:
                atomic_write_json(out / "summary.json", summary)
            if not rep.converged:
                break
        else:
            summary["status"] = "completed"
    finally:
        if recorder is not None:
            recorder.close()
    summary["elapsed_s"] = time.perf_counter() - t0
    result.state = state
    result.summary = summary
    if out is not None:
        atomic_write_json(out / "summary.json", summary)
        mesh = model.mesh
        arrays = {name: np.asarray(v) for name, v in fields.items() if v}
        atomic_write_npz(
            out / "fields.npz", nodes=mesh.nodes, elements=mesh.elements, lower=mesh.lower,
            upper=mesh.upper, lower_area=model.lower_area, **arrays,
        )
    return result
