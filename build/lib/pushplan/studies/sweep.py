"""``pushplan sweep``: run one scenario over parameter grids on a local process
pool or a Dask cluster, and tabulate the per-case summary numbers.

A sweep file (TOML) reads::

    name = "sweep_twist"                  # optional, defaults to the file stem
    description = "..."                   # optional
    base = "paper_case3.toml"             # base scenario, relative to this file
    run = "simulate"                      # case runner: "simulate" or "plan" (the base has a [plan] table)
    executor = "process"                  # "process" (local pool) or "dask"
    workers = 2                           # pool size / LocalCluster workers (default: CPU count)
    [set]                                 # overrides applied to every case
    "block.elements" = [8, 8, 3]
    [grid]                                # full factorial product, first key slowest
    "friction.mu_y" = [0.3, 0.15, 0.05]
    "load.direction_deg" = [0.0, 45.0, 90.0]
    [heatmap]                             # optional figure over two table columns
    x = "load.direction_deg"
    y = "mu_ratio"
    values = ["steady_twist_deg", "direction_deviation_deg"]
    file = "sweep_twist.png"              # written in the output folder

Override keys are dotted paths into the scenario: ``table.key`` for ``block``,
``material``, ``friction``, ``solver`` (and the raw extra tables); ``load.key`` sets
``key`` in every ``[[load]]`` entry that has it (``load.direction_deg`` is the push
angle of the polar entries); ``load[i].key`` sets it in entry ``i`` only.  Unquoted
dotted keys (nested TOML tables) mean the same.  Every case is expanded and
validated before anything runs.

Outputs in ``DIR``:

``sweep.json``
    The resolved sweep: base, overrides, and every case's id, parameters and key.
``cases/<id>/``
    The runner's files (``summary.json``, ``fields.npz`` for ``simulate``) and
    ``case.json`` (status, error, key), written last.  A rerun skips the cases
    whose ``case.json`` holds the same key and a finished status.
``results.csv`` (and ``results.parquet`` when pyarrow is installed)
    One row per case: ``case``, ``status`` (``completed``, ``failed``: solver
    failure, ``error``: exception), ``error``, the grid values, the resolved
    parameters and the summary numbers of :data:`RESULT_COLUMNS` (SI units,
    degrees), ``folder``.
the heat map
    ``[heatmap].file``, one panel per value column.

Workers compute in a scratch folder and send the files back, so a remote Dask
cluster needs no shared file system; the client writes every output.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import hashlib
import importlib
import importlib.util
import io
import itertools
import json
import math
import multiprocessing
import os
import re
import tempfile
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..outputs.atomic import atomic_write_bytes, atomic_write_json, prepare_output_dir
from ..config.files import read_toml
from ..config.scenario import ScenarioError, parse_scenario

EXECUTORS = ("process", "dask")
CASE_RUNNERS = {"simulate": "pushplan.studies.sweep:simulate_case", "plan": "pushplan.studies.sweep:plan_case"}
"""Runner name -> ``"module:function"`` with ``function(scenario, out_dir)`` writing a
``summary.json`` in the :mod:`pushplan.simulate` format (``status``, ``failure``,
``steps``) into the existing folder ``out_dir``."""
MAX_CASES = 10_000
CASE_FILE = "case.json"
FINISHED = ("completed", "failed")
"""Statuses a rerun skips: a solver failure is a deterministic outcome, an exception may not be."""
HEATMAP_SUFFIXES = (".png", ".svg", ".pdf")
SCHEDULER_TIMEOUT_S = 10
PARAMETER_COLUMNS = (
    "mu_x", "mu_y", "mu_ratio", "friction_angle_deg", "young", "poisson", "elements", "quadrature",
    "n_steps", "push_distance", "push_direction_deg",
)
RESULT_COLUMNS = (
    "steps_done", "twist_deg", "lower_yaw_deg", "direction_deviation_deg", "steady_twist_deg",
    "steady_twist_elliptic_deg", "step_deviation_deg", "lag", "normal_force", "max_slip", "dissipation",
    "min_step_dissipation", "max_equilibrium_error", "newton_iterations", "elapsed_s",
    "plan_final_error", "naive_final_error",
)
"""Per-case numbers from ``summary.json`` (empty unless the case completed):

``twist_deg``, ``lower_yaw_deg``
    The last step's values (:func:`pushplan.simulate.step_summary`).
``direction_deviation_deg``
    Signed angle from the net push (sum of the in-plane commands) to the lower-face
    centroid displacement at the end: where the lower face went, against where it
    was pushed.
``steady_twist_deg``
    Signed angle from the last command's push direction to the lag (upper minus
    lower centroid displacement): the direction in which the block is sheared.  In
    steady sliding it is constant, and for a block whose in-plane shear stiffness
    is isotropic it equals the angle of the sliding friction force of the elliptic
    law, ``steady_twist_elliptic_deg`` = ``atan2(mu_y^2 sin p, mu_x^2 cos p) - p``
    with ``p`` the push direction in the orthotropy frame.
``step_deviation_deg``
    Signed angle from the last command's push direction to the lower-face centroid
    increment of the last step; near zero once the lower face slides steadily.
``lag``, ``normal_force``, ``max_slip``
    The last step's values, m and N.
``dissipation``, ``min_step_dissipation``
    Sum and minimum over the steps, J.
``max_equilibrium_error``, ``newton_iterations``
    Maximum and sum over the steps.
``plan_final_error``, ``naive_final_error``
    ``run = "plan"`` only: FE-verified final position error of the plan and of the
    naive straight push, m.
"""

_PATH = re.compile(r"^(?P<table>[A-Za-z_]\w*)(?:\[(?P<index>\d+)\])?\.(?P<key>[A-Za-z_]\w*)$")
_SLUG = re.compile(r"[^A-Za-z0-9._=+-]+")


class SweepError(ScenarioError):
    """Invalid sweep file, override or option; the message names the key and value."""


@dataclass(frozen=True)
class Case:
    """One expanded case: ``params`` are the grid values, ``scenario`` the raw
    scenario dict with all overrides applied, ``key`` a hash of what it runs."""

    index: int
    case_id: str
    params: dict
    scenario: dict
    key: str
    columns: dict


@dataclass(frozen=True)
class Heatmap:
    x: str
    y: str
    values: tuple[str, ...]
    file: str


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file with its cases expanded."""

    name: str
    description: str
    path: Path
    base: Path
    run: str
    executor: str
    workers: int
    overrides: dict
    grid: dict
    cases: tuple[Case, ...]
    heatmap: Heatmap | None = None


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


# ---- sweep file -------------------------------------------------------------


def _flatten(prefix: str, table: dict) -> dict:
    """Nested TOML tables to dotted keys (``{"friction": {"mu_y": v}}`` -> ``{"friction.mu_y": v}``)."""
    out = {}
    for k, v in table.items():
        path = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            out.update(_flatten(path, v))
        else:
            out[path] = v
    return out


def _check_path(section: str, path: str) -> re.Match:
    m = _PATH.match(path)
    if m is None:
        raise SweepError(f"{section} key {path!r} must read table.key, load.key or load[i].key")
    if m["index"] is not None and m["table"] != "load":
        raise SweepError(f"{section} key {path!r}: only load entries take an index")
    return m


def apply_override(data: dict, path: str, value: Any) -> None:
    """Set the dotted ``path`` (see the module docstring) to ``value`` in the raw scenario dict ``data``."""
    m = _check_path("override", path)
    table, key = m["table"], m["key"]
    if table == "load":
        loads = data.get("load")
        if not isinstance(loads, list) or not loads:
            raise SweepError(f"{path}: the base scenario has no [[load]] entries")
        if m["index"] is not None:
            i = int(m["index"])
            if i >= len(loads):
                raise SweepError(f"{path}: the base scenario has {len(loads)} [[load]] entries, got index {i}")
            loads[i][key] = copy.deepcopy(value)
            return
        targets = [e for e in loads if isinstance(e, dict) and key in e]
        if not targets:
            raise SweepError(f"{path}: no [[load]] entry of the base scenario has {key}")
        for entry in targets:
            entry[key] = copy.deepcopy(value)
        return
    target = data.setdefault(table, {})
    if not isinstance(target, dict):
        raise SweepError(f"{path}: {table} is not a table in the base scenario")
    target[key] = copy.deepcopy(value)


def _slug(path: str, value: Any) -> str:
    text = "x".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value) if isinstance(value, list) else (
        f"{value:g}" if isinstance(value, float) else str(value))
    return _SLUG.sub("-", f"{path.rsplit('.', 1)[-1]}={text}")


def _case_key(run: str, scenario: dict) -> str:
    text = json.dumps({"run": run, "scenario": scenario}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _angle_deg(a, b) -> float | None:
    """Signed angle from 2D vector ``a`` to ``b``, degrees; None if either is zero."""
    ax, ay = float(a[0]), float(a[1])
    bx, by = float(b[0]), float(b[1])
    if (ax == 0 and ay == 0) or (bx == 0 and by == 0):
        return None
    return math.degrees(math.atan2(ax * by - ay * bx, ax * bx + ay * by))


def parameter_columns(resolved: dict) -> dict:
    """Table columns of a resolved scenario (``Scenario.to_dict()``): friction,
    material, mesh and the net in-plane push (m, degrees)."""
    fr, mat, block, load = resolved["friction"], resolved["material"], resolved["block"], resolved["load"]
    px = sum(c["dx"] for c in load)
    py = sum(c["dy"] for c in load)
    return {
        "mu_x": fr["mu_x"],
        "mu_y": fr["mu_y"],
        "mu_ratio": fr["mu_x"] / fr["mu_y"] if fr["mu_y"] > 0 else None,
        "friction_angle_deg": fr["angle_deg"],
        "young": mat["young"],
        "poisson": mat["poisson"],
        "elements": "x".join(str(n) for n in block["elements"]),
        "quadrature": block["quadrature"],
        "n_steps": len(load),
        "push_distance": math.hypot(px, py),
        "push_direction_deg": math.degrees(math.atan2(py, px)) if (px or py) else None,
    }


def _string(data: dict, key: str, default: str) -> str:
    v = data.get(key, default)
    if not isinstance(v, str) or not v:
        raise SweepError(f"{key} must be a non-empty string, got {v!r}")
    return v


def _positive_int(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise SweepError(f"{key} must be an integer >= 1, got {value!r}")
    return value


def _heatmap(data: Any, name: str, grid_keys: list[str]) -> Heatmap:
    if not isinstance(data, dict):
        raise SweepError(f"heatmap must be a table, got {data!r}")
    allowed = {"x", "y", "values", "file"}
    for k in data:
        if k not in allowed:
            raise SweepError(f"unknown key heatmap.{k} (allowed: {', '.join(sorted(allowed))})")
    axes = [*grid_keys, *PARAMETER_COLUMNS]
    for k in ("x", "y"):
        if data.get(k) not in axes:
            raise SweepError(f"heatmap.{k} must be a grid key or one of {PARAMETER_COLUMNS}, got {data.get(k)!r}")
    values = data.get("values")
    if not isinstance(values, list) or not values or any(v not in RESULT_COLUMNS for v in values):
        raise SweepError(f"heatmap.values must be a non-empty list from {RESULT_COLUMNS}, got {values!r}")
    file = data.get("file", f"{name}.png")
    if not isinstance(file, str) or Path(file).name != file or Path(file).suffix not in HEATMAP_SUFFIXES:
        raise SweepError(f"heatmap.file must be a file name ending in {'/'.join(HEATMAP_SUFFIXES)}, got {file!r}")
    return Heatmap(data["x"], data["y"], tuple(values), file)


def load_sweep(path) -> Sweep:
    """Read, validate and expand a sweep file; every case's scenario is validated.

    Raises
    ------
    SweepError, ScenarioError
        Unreadable or malformed file, unknown key, bad value (named), a case
        whose scenario is invalid (named with its grid values).
    """
    path = Path(path)
    data = read_toml(path, "sweep")
    top = {"name", "description", "base", "run", "executor", "workers", "set", "grid", "heatmap"}
    for k in data:
        if k not in top:
            raise SweepError(f"unknown key {k} (allowed: {', '.join(sorted(top))})")
    name = _string(data, "name", path.stem)
    description = data.get("description", "")
    if not isinstance(description, str):
        raise SweepError(f"description must be a string, got {description!r}")
    if "base" not in data:
        raise SweepError("missing key base (the base scenario file)")
    base = path.parent / _string(data, "base", "")
    base_data = read_toml(base, "base scenario")
    parse_scenario(base_data, name=base.stem)  # the base alone must be valid
    run = _string(data, "run", "simulate")
    if run not in CASE_RUNNERS:
        raise SweepError(f"run must be one of {tuple(CASE_RUNNERS)}, got {run!r}")
    executor = _string(data, "executor", "process")
    if executor not in EXECUTORS:
        raise SweepError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    workers = _positive_int("workers", data.get("workers", os.cpu_count() or 1))
    tables = {}
    for section in ("set", "grid"):
        raw = data.get(section, {})
        if not isinstance(raw, dict):
            raise SweepError(f"{section} must be a table, got {raw!r}")
        tables[section] = _flatten("", raw)
        for k in tables[section]:
            _check_path(section, k)
    overrides, grid = tables["set"], tables["grid"]
    if not grid:
        raise SweepError("grid must hold at least one key with a list of values")
    for k, values in grid.items():
        if k in overrides:
            raise SweepError(f"grid key {k!r} is also in [set]")
        if not isinstance(values, list) or not values:
            raise SweepError(f"grid.{k} must be a non-empty list, got {values!r}")
        seen = [json.dumps(v, sort_keys=True) for v in values]
        if len(set(seen)) != len(seen):
            raise SweepError(f"grid.{k} has repeated values: {values!r}")
    n_cases = math.prod(len(v) for v in grid.values())
    if n_cases > MAX_CASES:
        raise SweepError(f"grid expands to {n_cases} cases, more than {MAX_CASES}")
    for k, v in overrides.items():
        apply_override(base_data, k, v)
    width = max(3, len(str(n_cases - 1)))
    cases = []
    for index, values in enumerate(itertools.product(*grid.values())):
        params = dict(zip(grid, values))
        case_id = f"{index:0{width}d}_" + "_".join(_slug(k, v) for k, v in params.items())
        scenario = copy.deepcopy(base_data)
        label = ", ".join(f"{k}={v!r}" for k, v in params.items())
        try:
            for k, v in params.items():
                apply_override(scenario, k, v)
            scenario["name"] = f"{name}-{case_id}"
            resolved = parse_scenario(scenario).to_dict()
        except ValueError as exc:
            raise SweepError(f"case {index} ({label}): {exc}") from None
        if not resolved["load"]:
            raise SweepError(f"case {index} ({label}): no load steps to run")
        cases.append(Case(index, case_id, params, scenario, _case_key(run, scenario), parameter_columns(resolved)))
    heatmap = _heatmap(data["heatmap"], name, list(grid)) if "heatmap" in data else None
    if heatmap is not None:
        cells = {}
        for c in cases:
            values = [c.params.get(a, c.columns.get(a)) for a in (heatmap.x, heatmap.y)]
            for a, v in zip((heatmap.x, heatmap.y), values):
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise SweepError(f"heatmap axis {a} must be a finite number in every case, got {v!r}")
            cell = tuple(json.dumps(v) for v in values)
            if cell in cells:
                raise SweepError(
                    f"heatmap: cases {cells[cell]} and {c.index} share the cell {heatmap.x}, {heatmap.y} = "
                    f"{', '.join(cell)}; every other grid key must be fixed"
                )
            cells[cell] = c.index
    return Sweep(name, description, path, base, run, executor, workers, overrides, grid, tuple(cases), heatmap)


# ---- one case (runs on a worker) ----------------------------------------------


def simulate_case(scenario, out_dir: Path) -> None:
    """The ``simulate`` runner: :func:`pushplan.simulate.simulate` without a recording."""
    from ..run import simulate

    simulate(scenario, out_dir, recording=False)


def plan_case(scenario, out_dir: Path) -> None:
    """The ``plan`` runner: :func:`pushplan.planner.plan` for the case's ``[plan]`` table.

    Writes ``plan.json`` and a ``summary.json`` of the FE-verified rollout (press and
    planned commands) in the simulate format, so the table has the same columns plus
    the plan's final errors.
    """
    from ..outputs.atomic import atomic_write_json
    from ..planning.planner import parse_plan, plan, plan_commands_json, plan_document
    from ..run import StepSummary

    result = plan(scenario, parse_plan(scenario))
    doc = plan_document(result)
    atomic_write_json(out_dir / "plan.json", doc)
    reports = (*result.press_reports, *result.verified.reports)
    resolved = scenario.to_dict()
    resolved["load"] = plan_commands_json(result)
    atomic_write_json(out_dir / "summary.json", {
        "scenario": resolved,
        "elapsed_s": result.timings["total"],
        "status": "completed" if result.status != "not_converged" else "failed",
        "failure": None if result.status != "not_converged" else {"status": result.status, "message": result.message},
        "plan": {"status": result.status, "final_error": doc["final_error"],
                 "naive_final_error": doc["naive"]["final_error"]},
        "steps": [StepSummary.from_report(r).to_dict() for r in reports],
    })


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


# ---- results ----------------------------------------------------------------


def result_columns(summary: dict | None) -> dict:
    """The :data:`RESULT_COLUMNS` of a completed case's ``summary.json`` (None where undefined)."""
    out = dict.fromkeys(RESULT_COLUMNS)
    steps = (summary or {}).get("steps") or []
    if summary is None or summary.get("status") != "completed" or not steps:
        out["steps_done"] = len(steps)
        return out
    load = summary["scenario"]["load"]
    fr = summary["scenario"]["friction"]
    last = steps[-1]
    push = (sum(c["dx"] for c in load), sum(c["dy"] for c in load))
    cmd = load[len(steps) - 1]
    direction = (cmd["dx"], cmd["dy"])
    lower = last["lower_centroid"]
    prev = steps[-2]["lower_centroid"] if len(steps) > 1 else (0.0, 0.0)
    law = None
    if direction != (0.0, 0.0) and (fr["mu_x"] > 0 or fr["mu_y"] > 0):
        p = math.atan2(direction[1], direction[0]) - math.radians(fr["angle_deg"])
        law = _angle_deg((math.cos(p), math.sin(p)), (fr["mu_x"] ** 2 * math.cos(p), fr["mu_y"] ** 2 * math.sin(p)))
    out.update(
        steps_done=len(steps),
        twist_deg=last["twist_deg"],
        lower_yaw_deg=last["lower_yaw_deg"],
        direction_deviation_deg=_angle_deg(push, lower),
        steady_twist_deg=_angle_deg(direction, last["lag"]),
        steady_twist_elliptic_deg=law,
        step_deviation_deg=_angle_deg(direction, (lower[0] - prev[0], lower[1] - prev[1])),
        lag=math.hypot(*last["lag"][:2]),
        normal_force=last["normal_force"],
        max_slip=last["max_slip"],
        dissipation=sum(s["dissipation"] for s in steps),
        min_step_dissipation=min(s["dissipation"] for s in steps),
        max_equilibrium_error=max(s["equilibrium_error"] for s in steps),
        newton_iterations=sum(s["newton_iterations"] for s in steps),
        elapsed_s=summary["elapsed_s"],
    )
    if "plan" in summary:
        out.update(plan_final_error=summary["plan"]["final_error"]["position"],
                   naive_final_error=summary["plan"]["naive_final_error"]["position"])
    return out


def _cell(value: Any) -> Any:
    """A table cell: scalars as they are, lists as JSON text."""
    return json.dumps(value) if isinstance(value, (list, dict)) else value


def _row(case: Case, record: dict, summary: dict | None, folder: str) -> dict:
    row = {"case": case.case_id, "status": record["status"], "error": record["error"]}
    row.update({k: _cell(v) for k, v in case.params.items()})
    row.update(case.columns)
    row.update(result_columns(summary))
    row["folder"] = folder
    return row


def _write_tables(out: Path, rows: list[dict]) -> list[Path]:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows([{k: "" if v is None else v for k, v in r.items()} for r in rows])
    written = [atomic_write_bytes(out / "results.csv", buf.getvalue().encode())]
    if importlib.util.find_spec("pyarrow") is not None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        sink = pa.BufferOutputStream()
        pq.write_table(pa.Table.from_pylist(rows), sink)
        written.append(atomic_write_bytes(out / "results.parquet", sink.getvalue().to_pybytes()))
    return written


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _store(case_dir: Path, result: dict) -> tuple[dict, dict | None]:
    """Write a case's files, then ``case.json``; returns the record and the summary."""
    (case_dir / CASE_FILE).unlink(missing_ok=True)
    for rel, data in result["files"].items():
        target = case_dir / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(target, data)
    if result.get("traceback"):
        atomic_write_bytes(case_dir / "error.txt", result["traceback"].encode())
    summary = None
    if "summary.json" in result["files"]:
        with contextlib.suppress(ValueError):
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
    return {"status": status, "error": error}, summary


# ---- execution --------------------------------------------------------------


def _executor_error(exc: BaseException) -> dict:
    return {"files": {}, "error": " ".join(f"{type(exc).__name__}: {exc}".split()), "traceback": None}


def _run_local(tasks: list[dict], workers: int, on_result: Callable) -> None:
    # spawn: safe with the threads of fe_contact and of an in-process Dask cluster
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx) as pool:
        futures = {pool.submit(run_case, t): t for t in tasks}
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except Exception as exc:  # a worker died (BrokenProcessPool, MemoryError): record, go on
                result = _executor_error(exc)
            on_result(futures[fut], result)


def _run_dask(tasks: list[dict], client, on_result: Callable) -> None:
    from dask.distributed import as_completed as dask_completed

    futures = {client.submit(run_case, t, pure=False): t for t in tasks}
    for fut in dask_completed(list(futures)):
        try:
            result = fut.result()
        except Exception as exc:  # KilledWorker, lost connection: record, go on
            result = _executor_error(exc)
        on_result(futures[fut], result)


def _dask_client(stack: contextlib.ExitStack, scheduler: str | None, workers: int, cluster_options: dict):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise SweepError("executor 'dask' needs dask[distributed] (pip install 'dask[distributed]')") from None
    if scheduler is None:
        options = {"n_workers": workers, "threads_per_worker": 1, "dashboard_address": None,
                   "silence_logs": 40, **cluster_options}
        cluster = stack.enter_context(LocalCluster(**options))
        return stack.enter_context(Client(cluster))
    try:
        return stack.enter_context(Client(scheduler, timeout=SCHEDULER_TIMEOUT_S))
    except (OSError, ValueError, TypeError) as exc:
        message = " ".join(str(exc).split())
        raise SweepError(f"--scheduler {scheduler!r}: cannot connect ({type(exc).__name__}: {message})") from None


def run_sweep(
    sweep: Sweep,
    out_dir,
    executor: str | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    figure=None,
    rerun_failed: bool = False,
    cluster_options: dict | None = None,
    progress: Callable[[int, int, dict], None] | None = None,
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
    SweepError
        Bad option, dask missing, unreachable scheduler, unwritable figure path;
        all checked before the output folder is touched.
    """
    executor = "dask" if scheduler is not None else (executor or sweep.executor)
    if executor not in EXECUTORS:
        raise SweepError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    workers = sweep.workers if workers is None else _positive_int("workers", workers)
    if figure is not None:
        figure = Path(figure)
        if sweep.heatmap is None:
            raise SweepError(f"--figure {figure}: the sweep file has no [heatmap] table")
        if figure.suffix not in HEATMAP_SUFFIXES or not figure.parent.is_dir() or not os.access(figure.parent, os.W_OK):
            raise SweepError(f"--figure must be a {'/'.join(HEATMAP_SUFFIXES)} file in a writable folder, got {figure}")
    # one BLAS thread per case process (inherited by pool and LocalCluster workers),
    # also in the large dense kernels of fe_contact (fe_contact._threads)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "FE_CONTACT_DENSE_THREADS"):
        os.environ.setdefault(var, "1")
    with contextlib.ExitStack() as stack:
        client = _dask_client(stack, scheduler, workers, cluster_options or {}) if executor == "dask" else None
        out = prepare_output_dir(out_dir)
        cases_dir = out / "cases"
        cases_dir.mkdir(exist_ok=True)
        atomic_write_json(out / "sweep.json", {
            "name": sweep.name, "description": sweep.description, "sweep_file": str(sweep.path),
            "base": str(sweep.base), "run": sweep.run, "set": sweep.overrides, "grid": sweep.grid,
            "cases": [{"case": c.case_id, "params": c.params, "key": c.key} for c in sweep.cases],
        })
        rows: dict[int, dict] = {}
        result = SweepResult(rows=[])
        todo = []
        skip = ("completed",) if rerun_failed else FINISHED
        for case in sweep.cases:
            case_dir = cases_dir / case.case_id
            record = _read_json(case_dir / CASE_FILE)
            if record and record.get("key") == case.key and record.get("status") in skip:
                summary = _read_json(case_dir / "summary.json")
                rows[case.index] = _row(case, record, summary, f"cases/{case.case_id}")
                result.skipped.append(case.case_id)
            else:
                case_dir.mkdir(exist_ok=True)
                todo.append({"index": case.index, "run": sweep.run, "scenario": case.scenario})

        def on_result(task: dict, outcome: dict) -> None:
            case = sweep.cases[task["index"]]
            case_dir = cases_dir / case.case_id
            record, summary = _store(case_dir, outcome)
            record = {"case": case.case_id, "key": case.key, "params": case.params, **record}
            atomic_write_json(case_dir / CASE_FILE, record)
            rows[case.index] = _row(case, record, summary, f"cases/{case.case_id}")
            result.ran.append(case.case_id)
            if progress is not None:
                progress(len(result.ran), len(todo), rows[case.index])

        if todo:
            if client is not None:
                _run_dask(todo, client, on_result)
            else:
                _run_local(todo, workers, on_result)
    result.rows = [rows[i] for i in sorted(rows)]
    written = _write_tables(out, result.rows)
    result.outputs["tables"] = written
    if sweep.heatmap is not None:
        data = heatmap_figure(result.rows, sweep.heatmap, title=sweep.description or sweep.name)
        result.outputs["heatmap"] = [atomic_write_bytes(out / sweep.heatmap.file, data)]
        if figure is not None:
            result.outputs["heatmap"].append(atomic_write_bytes(figure, data))
    return result


# ---- heat map ---------------------------------------------------------------

LABELS = {
    "steady_twist_deg": "steady twist (deg)\nlag direction - push direction",
    "direction_deviation_deg": "lower-face direction deviation (deg)\nlower-face motion - push direction",
    "load.direction_deg": "push direction (deg from x)",
    "mu_ratio": "anisotropy mu_x / mu_y",
}


def heatmap_figure(rows: list[dict], spec: Heatmap, title: str = "") -> bytes:
    """One annotated heat map per value column over the ``spec.x`` x ``spec.y`` grid;
    cases that did not complete are grey.  Returns the encoded figure."""
    import matplotlib
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    xs = sorted({r[spec.x] for r in rows})
    ys = sorted({r[spec.y] for r in rows})
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="0.8")
    n = len(spec.values)
    fig = Figure(figsize=(1.2 + 0.75 * len(xs) * n, 1.6 + 0.5 * len(ys)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, column in zip(axes, spec.values):
        grid = np.full((len(ys), len(xs)), np.nan)
        for r in rows:
            if r["status"] == "completed" and r[column] is not None:
                grid[ys.index(r[spec.y]), xs.index(r[spec.x])] = r[column]
        finite = np.abs(grid[np.isfinite(grid)])
        vmax = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
        image = ax.imshow(np.ma.masked_invalid(grid), origin="lower", cmap=cmap, vmin=-vmax, vmax=vmax,
                          aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            text = "-" if np.isnan(v) else f"{v:.1f}".replace("-0.0", "0.0")
            ax.text(j, i, text, ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
        ax.set_yticks(range(len(ys)), [f"{v:.3g}" for v in ys])
        ax.set_xlabel(LABELS.get(spec.x, spec.x))
        ax.set_ylabel(LABELS.get(spec.y, spec.y))
        ax.set_title(LABELS.get(column, column), fontsize=9)
        fig.colorbar(image, ax=ax, shrink=0.9)
    if title:
        fig.suptitle(title, fontsize=9)
    buf = io.BytesIO()
    fig.savefig(buf, format=Path(spec.file).suffix[1:], dpi=120)
    return buf.getvalue()


# ---- command line -----------------------------------------------------------


def cmd_sweep(args) -> int:
    from ..errors import EXIT_SOLVER_FAILURE

    sweep = load_sweep(args.sweep)
    started = time.perf_counter()

    def progress(done: int, total: int, row: dict) -> None:
        detail = row["error"] or (
            f"steady twist {row['steady_twist_deg']:.3f} deg, deviation {row['direction_deviation_deg']:.3f} deg"
            if row["steady_twist_deg"] is not None and row["direction_deviation_deg"] is not None else "")
        print(f"[{done:>{len(str(total))}}/{total}] {row['case']}: {row['status']}  {detail}", flush=True)

    result = run_sweep(
        sweep, args.out, executor=args.executor, scheduler=args.scheduler, workers=args.workers,
        figure=args.figure, rerun_failed=args.rerun_failed, progress=None if args.quiet else progress,
    )
    counts = {s: sum(r["status"] == s for r in result.rows) for s in ("completed", "failed", "error")}
    print(f"{len(result.rows)} cases ({len(result.ran)} run, {len(result.skipped)} already finished): "
          f"{counts['completed']} completed, {counts['failed']} failed, {counts['error']} errors "
          f"in {time.perf_counter() - started:.1f} s")
    for paths in result.outputs.values():
        for p in paths:
            print(f"wrote {p}")
    return 0 if result.all_completed else EXIT_SOLVER_FAILURE


def register(subparsers) -> None:
    """Add the ``sweep`` subcommand."""
    p = subparsers.add_parser("sweep", help="run a scenario over parameter grids (local process pool or Dask)")
    p.add_argument("sweep", help="sweep TOML file (see pushplan.sweep)")
    p.add_argument("--out", required=True, help="output folder (results.csv, cases/, heat map); reruns resume")
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address (implies --executor dask)")
    p.add_argument("--executor", choices=EXECUTORS, help="override the sweep file's executor")
    p.add_argument("--workers", type=int, help="local pool / LocalCluster size (default: the file's, or CPU count)")
    p.add_argument("--figure", help="also write the heat map here, e.g. docs/figures/sweep_twist.png")
    p.add_argument("--rerun-failed", action="store_true", help="also rerun cases that ended in a solver failure")
    p.add_argument("--quiet", action="store_true", help="no per-case lines")
    p.set_defaults(func=cmd_sweep)
