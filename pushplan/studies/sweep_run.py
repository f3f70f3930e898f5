"""``run_sweep``: run a sweep's cases on a local process pool or a Dask cluster and
write its outputs.

Outputs in ``DIR``:

``sweep.json``
    The resolved sweep: base, overrides, and every case's id, parameters and key.
``cases/<id>/``
    The runner's files (``summary.json``, ``fields.npz`` for ``simulate``) and
    ``case.json`` (status, error, key), the folder swapped in whole
    (:mod:`pushplan.outputs.transaction`): a killed sweep leaves each case folder as it
    was or complete.  A rerun skips the cases whose ``case.json`` holds the same key
    and a finished status.  The sweep folder is locked while a sweep runs in it.
``results.csv`` (and ``results.parquet``), the heat map
    :mod:`pushplan.studies.sweep_tables`.

Workers compute in a scratch folder and send the files back, so a remote Dask
cluster needs no shared file system; the client writes every output.  Each local
worker process runs one BLAS / OpenMP thread and one dense-kernel thread
(:data:`THREAD_VARIABLES`, unless the caller's environment sets them); the
caller's own environment is left as it is.  Pool workers die with the sweep, a dead
worker's cases run again, Ctrl-C stops the workers (:mod:`.sweep_pool`).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import tempfile
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..config.scenario import Scenario, parse_scenario
from ..config.sweep import EXECUTORS, HEATMAP_SUFFIXES, Sweep
from ..config.validate import choice, integer
from ..errors import InputError
from ..outputs.atomic import atomic_write_bytes, atomic_write_json, prepare_output_dir
from ..outputs.transaction import (OutputLock, check_output_path, output_file_lock, output_transaction, recover_siblings,
                                     remove_temporaries)
from ..run import RunStatus, RunSummary, StepSummary
from .sweep_pool import SCHEDULER_TIMEOUT_S, connect, run_dask, run_local, worker_environment
from .sweep_tables import case_row, heatmap_figure, write_tables

CASE_RUNNERS = {"simulate": "pushplan.studies.sweep_run:simulate_case",
                "plan": "pushplan.studies.sweep_run:plan_case"}
"""Runner name (:data:`pushplan.config.sweep.RUNNERS`) -> ``"module:function"`` with
``function(scenario, out_dir)`` writing a ``summary.json`` in the
:class:`~pushplan.run.RunSummary` format (``status``, ``failure``, ``steps``) into
the existing folder ``out_dir``."""
CASE_FILE = "case.json"
FINISHED = ("completed", "failed")
"""Statuses a rerun skips: a solver failure is a deterministic outcome, an exception may not be."""
@dataclass
class SweepResult:
    """Rows of ``results.csv`` (in case order) and which cases ran or were skipped."""

    rows: list[dict]
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    outputs: dict = field(default_factory=dict)

    @property
    def all_completed(self) -> bool:
        return all(r["status"] == "completed" for r in self.rows)


# ---- one case (runs on a worker) ----------------------------------------------


def simulate_case(scenario: Scenario, out_dir: Path) -> None:
    """The ``simulate`` runner: :func:`pushplan.run.simulate` without a recording."""
    from ..run import simulate

    simulate(scenario, out_dir, recording=False)


@dataclass(frozen=True)
class PlanCaseSummary:
    """``summary.json`` of a ``plan`` case: the FE-verified rollout (press and planned
    commands) as a :class:`~pushplan.run.RunSummary`, and the plan's outcome.  A plan
    that did not converge is a failed run whose failure is the planner's status."""

    run: RunSummary
    plan_status: str
    message: str
    final_error: dict
    naive_final_error: dict

    def to_dict(self) -> dict:
        """The simulate format plus ``plan`` (status and the final errors of plan and naive push)."""
        d = self.run.to_dict()
        return {
            "scenario": d["scenario"], "elapsed_s": d["elapsed_s"], "status": d["status"],
            "failure": None if self.run.completed else {"status": self.plan_status, "message": self.message},
            "plan": {"status": self.plan_status, "final_error": self.final_error,
                     "naive_final_error": self.naive_final_error},
            "steps": d["steps"],
        }


def plan_case(scenario: Scenario, out_dir: Path) -> None:
    """The ``plan`` runner: :func:`pushplan.planning.planner.plan` for the case's
    ``[plan]`` table; writes ``plan.json`` and a :class:`PlanCaseSummary`, so that the
    table has the simulate columns plus the plan's final errors."""
    from ..planning.planner import parse_plan, plan, plan_commands_json, plan_document

    result = plan(scenario, parse_plan(scenario))
    doc = plan_document(result)
    atomic_write_json(out_dir / "plan.json", doc)
    converged = result.status != "not_converged"
    run = RunSummary(
        scenario={**scenario.to_dict(), "load": plan_commands_json(result)},
        steps=[StepSummary.from_report(r) for r in (*result.press_reports, *result.verified.reports)],
        status=RunStatus.COMPLETED if converged else RunStatus.FAILED, elapsed_s=result.timings["total"],
    )
    summary = PlanCaseSummary(run, result.status, result.message, doc["final_error"], doc["naive"]["final_error"])
    atomic_write_json(out_dir / "summary.json", summary.to_dict())


def _runner(run: str) -> Callable:
    module, func = CASE_RUNNERS[run].split(":")
    return getattr(importlib.import_module(module), func)


def run_case(task: dict) -> dict:
    """Run one case in a scratch folder; never raises.

    Parameters
    ----------
    task : dict
        ``scenario`` (raw dict), ``run`` (runner name).

    Returns
    -------
    dict
        ``files`` (relative path -> bytes of everything the runner wrote),
        ``error`` (None or a one-line message) and ``traceback``.
    """
    error = tb = None
    with tempfile.TemporaryDirectory(prefix="pushplan-case-") as tmp:
        try:
            _runner(task["run"])(parse_scenario(task["scenario"]), Path(tmp))
        except Exception as exc:  # any failure of a case is data for the table, not a crash of the sweep
            error = " ".join(f"{type(exc).__name__}: {exc}".split())
            tb = traceback.format_exc()
        files = {p.relative_to(tmp).as_posix(): p.read_bytes() for p in sorted(Path(tmp).rglob("*")) if p.is_file()}
    return {"files": files, "error": error, "traceback": tb}


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):  # absent or half-written: the case runs again
        return None


def _store(case_dir: Path, result: dict, record: dict) -> tuple[dict, dict | None]:
    """Write a case's folder as one transaction (files, ``error.txt``, ``case.json``
    last): a killed sweep leaves the previous complete folder or the new one.
    Returns the ``case.json`` record and the summary."""
    summary = None
    if "summary.json" in result["files"]:
        with contextlib.suppress(ValueError):  # a corrupt summary is reported below
            summary = json.loads(result["files"]["summary.json"])
    if result["error"] is not None:
        status, error = "error", result["error"]
    elif not isinstance(summary, dict):
        status, error = "error", "the runner wrote no summary.json"
    elif summary.get("status") == "completed":
        status, error = "completed", None
    else:
        failure = summary.get("failure") or {}
        status, error = "failed", failure.get("message", f"run ended with status {summary.get('status')!r}")
    record = {**record, "status": status, "error": error}
    with output_transaction(case_dir, owned=None, lock=False) as tx:  # the sweep holds the lock
        for rel, data in result["files"].items():
            target = tx.path / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(target, data)
        if result.get("traceback"):
            atomic_write_bytes(tx.path / "error.txt", result["traceback"].encode())
        atomic_write_json(tx.path / CASE_FILE, record)
    return record, summary


# ---- execution --------------------------------------------------------------


def _dask_client(stack: contextlib.ExitStack, scheduler: str | None, workers: int, cluster_options: dict):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise InputError("executor 'dask' needs dask[distributed] (pip install 'dask[distributed]')") from None
    if scheduler is None:
        options = {"n_workers": workers, "threads_per_worker": 1, "dashboard_address": None,
                   "silence_logs": 40, **cluster_options}
        if options.get("processes", True):  # worker processes (nannies) get the thread variables
            options.setdefault("env", worker_environment())
        cluster = stack.enter_context(LocalCluster(**options))
        return stack.enter_context(Client(cluster))
    return stack.enter_context(connect(scheduler, SCHEDULER_TIMEOUT_S))


# ---- the sweep ------------------------------------------------------------------


def _options(sweep: Sweep, executor, scheduler, workers, figure) -> tuple[str, int, Path | None]:
    """The executor, pool size and extra figure path, checked."""
    executor = "dask" if scheduler is not None else choice("executor", executor or sweep.executor, EXECUTORS)
    workers = sweep.workers if workers is None else integer("workers", workers, 1)
    if figure is not None:
        figure = Path(figure)
        if sweep.heatmap is None:
            raise InputError(f"--figure {figure}: the sweep file has no [heatmap] table")
        if figure.suffix not in HEATMAP_SUFFIXES:
            raise InputError(f"--figure must be a {'/'.join(HEATMAP_SUFFIXES)} file, got {figure}")
        figure = check_output_path(figure, "--figure", folder=False)
    return executor, workers, figure


def _sweep_json(sweep: Sweep) -> dict:
    return {
        "name": sweep.name, "description": sweep.description, "sweep_file": str(sweep.path),
        "base": str(sweep.base), "run": sweep.run, "set": sweep.overrides, "grid": sweep.grid,
        "cases": [{"case": c.case_id, "params": c.params, "key": c.key} for c in sweep.cases],
    }


class _Collector:
    """The rows as cases finish or are found finished, and the ``case.json`` records."""

    def __init__(self, sweep: Sweep, cases_dir: Path, progress: Callable | None):
        self.sweep, self.cases_dir, self.progress = sweep, cases_dir, progress
        self.rows: dict[int, dict] = {}
        self.result = SweepResult(rows=[])
        self.todo: list[dict] = []

    def scan(self, rerun_failed: bool) -> None:
        """Rows of the cases finished with the same key; the other cases go to ``todo``."""
        skip = ("completed",) if rerun_failed else FINISHED
        for case in self.sweep.cases:
            case_dir = self.cases_dir / case.case_id
            record = _read_json(case_dir / CASE_FILE)
            if record and record.get("key") == case.key and record.get("status") in skip:
                summary = _read_json(case_dir / "summary.json")
                self.rows[case.index] = case_row(case, record, summary, f"cases/{case.case_id}")
                self.result.skipped.append(case.case_id)
            else:
                self.todo.append({"index": case.index, "run": self.sweep.run, "scenario": case.scenario})

    def on_result(self, task: dict, outcome: dict) -> None:
        """Store a case's files, then its ``case.json``; its row."""
        case = self.sweep.cases[task["index"]]
        case_dir = self.cases_dir / case.case_id
        record, summary = _store(case_dir, outcome, {"case": case.case_id, "key": case.key, "params": case.params})
        self.rows[case.index] = case_row(case, record, summary, f"cases/{case.case_id}")
        self.result.ran.append(case.case_id)
        if self.progress is not None:
            self.progress(len(self.result.ran), len(self.todo), self.rows[case.index])


def run_sweep(sweep: Sweep, out_dir, executor: str | None = None, scheduler: str | None = None,
              workers: int | None = None, figure=None, rerun_failed: bool = False,
              cluster_options: dict | None = None, progress: Callable[[int, int, dict], None] | None = None,
              ) -> SweepResult:
    """Run the cases not finished yet, then write the tables and the heat map.

    Parameters
    ----------
    sweep : Sweep
    out_dir : path
        Output folder (created).
    executor : {"process", "dask"}, optional
        Overrides the sweep file's; ``scheduler`` implies ``"dask"``.
    scheduler : str, optional
        Address of a running Dask scheduler; without it ``"dask"`` starts a
        ``LocalCluster`` of ``workers`` single-threaded workers.
    workers : int, optional
        Overrides the sweep file's pool / LocalCluster size.
    figure : path, optional
        Also write the heat map there (e.g. ``docs/figures/sweep_twist.png``).
    rerun_failed : bool
        Also rerun cases that finished with a solver failure.
    cluster_options : dict, optional
        Extra ``LocalCluster`` arguments (e.g. ``processes=False``).
    progress : callable, optional
        ``progress(done, total, row)`` after each case that ran.

    Raises
    ------
    InputError
        Bad option, dask missing, unreachable scheduler, unwritable figure path;
        all checked before the output folder is touched.
    """
    executor, workers, figure = _options(sweep, executor, scheduler, workers, figure)
    with contextlib.ExitStack() as stack:
        client = _dask_client(stack, scheduler, workers, cluster_options or {}) if executor == "dask" else None
        out = _locked_output(stack, out_dir, sweep)
        if figure is not None:
            stack.enter_context(output_file_lock(figure, "--figure"))
        state = _Collector(sweep, out / "cases", progress)
        state.scan(rerun_failed)
        if state.todo and client is not None:
            run_dask(run_case, state.todo, client, state.on_result)
        elif state.todo:
            run_local(run_case, state.todo, workers, state.on_result)
        result = state.result
        result.rows = [state.rows[i] for i in sorted(state.rows)]
        result.outputs["tables"] = write_tables(out, result.rows)
        if sweep.heatmap is not None:
            data = heatmap_figure(result.rows, sweep.heatmap, title=sweep.description or sweep.name)
            result.outputs["heatmap"] = [atomic_write_bytes(out / sweep.heatmap.file, data)]
            if figure is not None:
                result.outputs["heatmap"].append(atomic_write_bytes(figure, data))
    return result


def _locked_output(stack: contextlib.ExitStack, out_dir, sweep: Sweep) -> Path:
    """The sweep folder, locked for the run (a second sweep into it refuses), with the
    leftovers of killed runs repaired or removed; ``sweep.json`` written."""
    out = check_output_path(out_dir)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {out}: {exc.strerror}") from None
    lock = OutputLock(out)
    lock.acquire()
    stack.callback(lock.release)
    out = prepare_output_dir(out)
    (out / "cases").mkdir(exist_ok=True)
    recover_siblings(out / "cases")
    remove_temporaries(out)
    atomic_write_json(out / "sweep.json", _sweep_json(sweep))
    return out
