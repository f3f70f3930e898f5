"""The sweep's results: one table row per case (``results.csv``, and
``results.parquet`` when pyarrow is installed) and the heat-map figure.

A row holds ``case``, ``status`` (``completed``, ``failed``: solver failure,
``error``: exception), ``error``, the grid values, the
:data:`~pushplan.config.sweep.PARAMETER_COLUMNS` of the resolved scenario, the
:data:`~pushplan.config.sweep.RESULT_COLUMNS` of its ``summary.json`` and ``folder``.

Result columns (empty unless the case completed; SI units, degrees):

``steps_done``
    Converged steps (also for a case that did not complete).
``lower_direction_deviation_deg``, ``lower_yaw_deg``
    The last step's values (:class:`pushplan.run.StepSummary`; the deviation, from the
    upper- to the lower-face travel, empty while the lower face sticks).
``direction_deviation_deg``
    Signed angle from the net push (sum of the in-plane commands) to the lower-face
    centroid displacement at the end: where the lower face went, against where it
    was pushed.
``lag_angle_deg``
    Signed angle from the last command's push direction to the lag (upper minus
    lower centroid displacement): the direction in which the block is sheared.  In
    steady sliding it is constant, and for a block whose in-plane shear stiffness
    is isotropic it equals the angle of the sliding friction force of the elliptic
    law, ``lag_angle_elliptic_deg`` = ``atan2(mu_y^2 sin p, mu_x^2 cos p) - p``
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
``twist_deg``, ``steady_twist_deg``, ``steady_twist_elliptic_deg``
    The names before issue 33 ("twist" named two different angles), kept one release
    as aliases of ``lower_direction_deviation_deg``, ``lag_angle_deg``,
    ``lag_angle_elliptic_deg``.
"""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import math
from pathlib import Path
from typing import Any

from ..config.sweep import RESULT_COLUMNS, Case, Heatmap
from ..outputs.atomic import atomic_write_bytes


def _angle_deg(a, b) -> float | None:
    """Signed angle from 2D vector ``a`` to ``b``, degrees; None if either is zero."""
    ax, ay = float(a[0]), float(a[1])
    bx, by = float(b[0]), float(b[1])
    if (ax == 0 and ay == 0) or (bx == 0 and by == 0):
        return None
    return math.degrees(math.atan2(ax * by - ay * bx, ax * bx + ay * by))


def result_columns(summary: dict | None) -> dict:
    """The :data:`RESULT_COLUMNS` of a case's ``summary.json`` (None where undefined)."""
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
        lower_direction_deviation_deg=last.get("lower_direction_deviation_deg", last.get("twist_deg")),
        lower_yaw_deg=last["lower_yaw_deg"],
        direction_deviation_deg=_angle_deg(push, lower),
        lag_angle_deg=_angle_deg(direction, last["lag"]),
        lag_angle_elliptic_deg=law,
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
    out.update(twist_deg=out["lower_direction_deviation_deg"], steady_twist_deg=out["lag_angle_deg"],
               steady_twist_elliptic_deg=out["lag_angle_elliptic_deg"])  # aliases, one release
    if "plan" in summary:
        out.update(plan_final_error=summary["plan"]["final_error"]["position"],
                   naive_final_error=summary["plan"]["naive_final_error"]["position"])
    return out


def _cell(value: Any) -> Any:
    """A table cell: scalars as they are, lists as JSON text."""
    return json.dumps(value) if isinstance(value, (list, dict)) else value


def case_row(case: Case, record: dict, summary: dict | None, folder: str) -> dict:
    """The table row of a case: ``record`` is its ``case.json`` (``status``, ``error``),
    ``summary`` its ``summary.json`` (None if absent), ``folder`` relative to the output."""
    row = {"case": case.case_id, "status": record["status"], "error": record["error"]}
    row.update({k: _cell(v) for k, v in case.params.items()})
    row.update(case.columns)
    row.update(result_columns(summary))
    row["folder"] = folder
    return row


def write_tables(out: Path, rows: list[dict]) -> list[Path]:
    """``results.csv`` (None as an empty cell) and, with pyarrow, ``results.parquet`` in ``out``."""
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


# ---- heat map ---------------------------------------------------------------

LABELS = {
    "lag_angle_deg": "lag angle (deg)\nshear (lag) direction - push direction",
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
    for ax, column in zip(axes, spec.values, strict=True):
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
