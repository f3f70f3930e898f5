"""Sweep files (TOML): the schema, its validation, and the expansion into cases.

A sweep file reads::

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
    values = ["lag_angle_deg", "direction_deviation_deg"]
    file = "sweep_twist.png"              # written in the output folder

Override keys are dotted paths into the scenario: ``table.key`` for ``block``,
``material``, ``friction``, ``solver`` (and the raw extra tables); ``load.key`` sets
``key`` in every ``[[load]]`` entry that has it (``load.direction_deg`` is the push
angle of the polar entries); ``load[i].key`` sets it in entry ``i`` only.  Unquoted
dotted keys (nested TOML tables) mean the same.  Every case is expanded and its
scenario validated when the file is read; errors are :class:`InputError` naming
the key (and the case's grid values).  ``parse_sweep(sweep.to_dict(), sweep.path)``
gives ``sweep`` back.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..limits import MAX_WORKERS
from .files import read_toml
from .scenario import parse_scenario
from .validate import Table

EXECUTORS = ("process", "dask")
RUNNERS = ("simulate", "plan")
"""Case runners (:data:`pushplan.studies.sweep_run.CASE_RUNNERS`)."""
MAX_CASES = 10_000
HEATMAP_SUFFIXES = (".png", ".svg", ".pdf")
TOP_KEYS = {"name", "description", "base", "run", "executor", "workers", "set", "grid", "heatmap"}
HEATMAP_KEYS = {"x", "y", "values", "file"}
PARAMETER_COLUMNS = (
    "mu_x", "mu_y", "mu_ratio", "friction_angle_deg", "young", "poisson", "elements", "quadrature",
    "n_steps", "push_distance", "push_direction_deg",
)
"""Table columns of a case's resolved scenario (:func:`parameter_columns`)."""
RESULT_COLUMNS = (
    "steps_done", "lower_direction_deviation_deg", "lower_yaw_deg", "direction_deviation_deg", "lag_angle_deg",
    "lag_angle_elliptic_deg", "step_deviation_deg", "lag", "normal_force", "max_slip", "dissipation",
    "min_step_dissipation", "max_equilibrium_error", "newton_iterations", "elapsed_s",
    "plan_final_error", "naive_final_error", "twist_deg", "steady_twist_deg", "steady_twist_elliptic_deg",
)
"""Table columns of a case's outcome (:func:`pushplan.studies.sweep_tables.result_columns`);
the last three are the names before issue 33, kept one release as aliases of
``lower_direction_deviation_deg``, ``lag_angle_deg`` and ``lag_angle_elliptic_deg``."""

_PATH = re.compile(r"^(?P<table>[A-Za-z_]\w*)(?:\[(?P<index>\d+)\])?\.(?P<key>[A-Za-z_]\w*)$")
_SLUG = re.compile(r"[^A-Za-z0-9._=+-]+")  # ids are ASCII; short_case_id bounds their length

SweepError = InputError  # the name earlier versions exported


@dataclass(frozen=True)
class Case:
    """One expanded case: ``params`` are the grid values, ``scenario`` the raw
    scenario dict with all overrides applied, ``key`` a hash of what it runs,
    ``columns`` the :data:`PARAMETER_COLUMNS` of its resolved scenario."""

    index: int
    case_id: str
    params: dict
    scenario: dict
    key: str
    columns: dict


@dataclass(frozen=True)
class Heatmap:
    """A heat-map figure: ``values`` columns over the ``x`` x ``y`` columns, into ``file``."""

    x: str
    y: str
    values: tuple[str, ...]
    file: str

    def to_dict(self) -> dict:
        return {"x": self.x, "y": self.y, "values": list(self.values), "file": self.file}


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file with its cases expanded; ``overrides`` and ``grid`` by dotted key."""

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

    def to_dict(self) -> dict:
        """The sweep-file tables (``base`` relative to the file's folder where it lies under it)."""
        try:
            base = self.base.relative_to(self.path.parent)
        except ValueError:  # an absolute base outside the file's folder
            base = self.base
        out = {
            "name": self.name, "description": self.description, "base": base.as_posix(), "run": self.run,
            "executor": self.executor, "workers": self.workers, "set": copy.deepcopy(self.overrides),
            "grid": copy.deepcopy(self.grid),
        }
        if self.heatmap is not None:
            out["heatmap"] = self.heatmap.to_dict()
        return out


# ---- override paths -------------------------------------------------------------------


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
        raise InputError(f"{section} key {path!r} must read table.key, load.key or load[i].key")
    if m["index"] is not None and m["table"] != "load":
        raise InputError(f"{section} key {path!r}: only load entries take an index")
    return m


def apply_override(data: dict, path: str, value: Any) -> None:
    """Set the dotted ``path`` (see the module docstring) to ``value`` in the raw scenario dict ``data``."""
    m = _check_path("override", path)
    table, key = m["table"], m["key"]
    if table != "load":
        target = data.setdefault(table, {})
        if not isinstance(target, dict):
            raise InputError(f"{path}: {table} is not a table in the base scenario")
        target[key] = copy.deepcopy(value)
        return
    loads = data.get("load")
    if not isinstance(loads, list) or not loads:
        raise InputError(f"{path}: the base scenario has no [[load]] entries")
    if m["index"] is not None:
        i = int(m["index"])
        if i >= len(loads):
            raise InputError(f"{path}: the base scenario has {len(loads)} [[load]] entries, got index {i}")
        targets = [loads[i]]
    else:
        targets = [e for e in loads if isinstance(e, dict) and key in e]
        if not targets:
            raise InputError(f"{path}: no [[load]] entry of the base scenario has {key}")
    for entry in targets:
        entry[key] = copy.deepcopy(value)


# ---- cases ------------------------------------------------------------------------------


MAX_CASE_ID = 80
"""Longest case id (a folder name): longer ones keep their first characters and end
in a hash of the whole id, so that long grid values never make a file name too long."""


def short_case_id(case_id: str) -> str:
    """``case_id``, or its first characters and a 12-digit hash of it when longer than
    :data:`MAX_CASE_ID`."""
    if len(case_id) <= MAX_CASE_ID:
        return case_id
    digest = hashlib.sha256(case_id.encode()).hexdigest()[:12]
    return f"{case_id[:MAX_CASE_ID - 13]}~{digest}"


def _slug(path: str, value: Any) -> str:
    text = "x".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value) if isinstance(value, list) else (
        f"{value:g}" if isinstance(value, float) else str(value))
    return _SLUG.sub("-", f"{path.rsplit('.', 1)[-1]}={text}")


def _case_key(run: str, scenario: dict) -> str:
    text = json.dumps({"run": run, "scenario": scenario}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


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


def _check_plan(scenario) -> None:
    """A case of a ``run = "plan"`` sweep: its ``[plan]`` table present and valid (a
    world-frame plan is checked by the runner, which reads the MJCF scene)."""
    from .plan import parse_plan

    table = scenario.extra.get("plan")
    if table is None:
        raise InputError('run = "plan" needs a [plan] table in the base scenario (or set in the sweep)')
    if not (isinstance(table, dict) and table.get("frame") == "world"):
        parse_plan(scenario)


def expand_cases(name: str, run: str, base_data: dict, overrides: dict, grid: dict) -> tuple[Case, ...]:
    """The full factorial product of ``grid`` (first key slowest) over the base
    scenario with ``overrides``; every case's scenario validated.

    Raises
    ------
    InputError
        A case's scenario is invalid or has no load steps (named with its grid values).
    """
    base_data = copy.deepcopy(base_data)
    for k, v in overrides.items():
        apply_override(base_data, k, v)
    width = max(3, len(str(math.prod(len(v) for v in grid.values()) - 1)))
    cases = []
    for index, values in enumerate(itertools.product(*grid.values())):
        params = dict(zip(grid, values, strict=True))
        case_id = short_case_id(f"{index:0{width}d}_" + "_".join(_slug(k, v) for k, v in params.items()))
        scenario = copy.deepcopy(base_data)
        label = ", ".join(f"{k}={v!r}" for k, v in params.items())
        try:
            for k, v in params.items():
                apply_override(scenario, k, v)
            scenario["name"] = f"{name}-{case_id}"
            parsed = parse_scenario(scenario)
            if run == "plan":
                _check_plan(parsed)
            resolved = parsed.to_dict()
        except InputError as exc:
            raise InputError(f"case {index} ({label}): {exc}") from None
        if not resolved["load"]:
            raise InputError(f"case {index} ({label}): no load steps to run")
        cases.append(Case(index, case_id, params, scenario, _case_key(run, scenario), parameter_columns(resolved)))
    return tuple(cases)


# ---- the file -----------------------------------------------------------------------------


def _dotted_table(top: Table, section: str) -> dict:
    """``[set]`` / ``[grid]`` by dotted key, each key a valid override path."""
    raw = top.data.get(section, {})
    if not isinstance(raw, dict):
        raise InputError(f"{section} must be a table, got {raw!r}")
    flat = _flatten("", raw)
    for k in flat:
        _check_path(section, k)
    return flat


def _check_grid(grid: dict, overrides: dict) -> None:
    if not grid:
        raise InputError("grid must hold at least one key with a list of values")
    for k, values in grid.items():
        if k in overrides:
            raise InputError(f"grid key {k!r} is also in [set]")
        if not isinstance(values, list) or not values:
            raise InputError(f"grid.{k} must be a non-empty list, got {values!r}")
        seen = [json.dumps(v, sort_keys=True) for v in values]
        if len(set(seen)) != len(seen):
            raise InputError(f"grid.{k} has repeated values: {values!r}")
    n_cases = math.prod(len(v) for v in grid.values())
    if n_cases > MAX_CASES:
        raise InputError(f"grid expands to {n_cases} cases, more than {MAX_CASES}")


def _heatmap(top: Table, name: str, grid_keys: list[str]) -> Heatmap | None:
    if "heatmap" not in top:
        return None
    t = top.table("heatmap", HEATMAP_KEYS)
    axes = (*grid_keys, *PARAMETER_COLUMNS)
    x, y = t.choice("x", axes, None), t.choice("y", axes, None)
    values = t.data.get("values")
    if not isinstance(values, list) or not values or any(v not in RESULT_COLUMNS for v in values):
        raise InputError(f"heatmap.values must be a non-empty list from {RESULT_COLUMNS}, got {values!r}")
    file = t.string("file", f"{name}.png")
    if Path(file).name != file or Path(file).suffix not in HEATMAP_SUFFIXES:
        raise InputError(f"heatmap.file must be a file name ending in {'/'.join(HEATMAP_SUFFIXES)}, got {file!r}")
    return Heatmap(x, y, tuple(values), file)


def _check_heatmap_cells(heatmap: Heatmap, cases: tuple[Case, ...]) -> None:
    """Both axes numeric in every case, and no two cases on one cell."""
    cells = {}
    for c in cases:
        values = [c.params.get(a, c.columns.get(a)) for a in (heatmap.x, heatmap.y)]
        for a, v in zip((heatmap.x, heatmap.y), values, strict=True):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"heatmap axis {a} must be a finite number in every case, got {v!r}")
        cell = tuple(json.dumps(v) for v in values)
        if cell in cells:
            raise InputError(
                f"heatmap: cases {cells[cell]} and {c.index} share the cell {heatmap.x}, {heatmap.y} = "
                f"{', '.join(cell)}; every other grid key must be fixed"
            )
        cells[cell] = c.index


def parse_sweep(data: dict, path) -> Sweep:
    """Validate and expand a sweep given as tables (the parsed TOML, or
    ``Sweep.to_dict()``); ``path`` is the sweep file (``base`` is relative to its folder).

    Raises
    ------
    InputError
        Unknown key, bad value (named), unreadable or invalid base scenario, a case
        whose scenario is invalid (named with its grid values).
    """
    path = Path(path)
    top = Table(data, "", TOP_KEYS, required={"base"})
    name = top.string("name", path.stem, nonempty=True)
    description = top.string("description", "")
    base = path.parent / top.string("base", nonempty=True)
    base_data = read_toml(base, "base scenario")
    parse_scenario(base_data, name=base.stem)  # the base alone must be valid
    run = top.choice("run", RUNNERS, "simulate")
    executor = top.choice("executor", EXECUTORS, "process")
    workers = top.integer("workers", os.cpu_count() or 1, minimum=1, maximum=MAX_WORKERS)
    overrides, grid = _dotted_table(top, "set"), _dotted_table(top, "grid")
    _check_grid(grid, overrides)
    cases = expand_cases(name, run, base_data, overrides, grid)
    heatmap = _heatmap(top, name, list(grid))
    if heatmap is not None:
        _check_heatmap_cells(heatmap, cases)
    return Sweep(name, description, path, base, run, executor, workers, overrides, grid, cases, heatmap)


def load_sweep(path) -> Sweep:
    """Read, validate and expand a sweep file (:func:`parse_sweep`).

    Raises
    ------
    InputError
        Missing or unreadable file, malformed TOML, or what :func:`parse_sweep` raises.
    """
    return parse_sweep(read_toml(path, "sweep"), path)
