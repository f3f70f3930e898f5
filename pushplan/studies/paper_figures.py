"""Figures 6-10 of the paper reproduction (matplotlib, PNG at 110 dpi): contour plots
on the lower face (reference coordinates, mm) of the three cases side by side on
one shared colour scale, and the magnified deformed blocks with a top view of the
face-centroid paths."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from fe_contact import NodeStatus

from ..config.scenario import Scenario
from ..outputs.atomic import atomic_write_bytes, prepare_output_dir
from ..run import Run
from .paper_cases import direction_deg, lower_grid, node_field, push_direction

MAGNIFICATION = 20.0
"""Factor on the deformation (displacement minus the lower-face mean translation) in fig. 10."""
CONTOUR_LEVELS = 21
FIGURES = {
    "fig06_slip_compression": ("slip", "first", "Fig. 6: slip after compression"),
    "fig07_rn_compression": ("r_n", "first", "Fig. 7: nodal normal reaction r_n after compression"),
    "fig07b_pressure_compression": ("pressure", "first", "Fig. 7b: contact pressure after compression"),
    "fig08_slip_sliding": ("slip", "last", "Fig. 8: slip after sliding"),
    "fig09_rn_sliding": ("r_n", "last", "Fig. 9: nodal normal reaction r_n after sliding"),
    "fig09b_pressure_sliding": ("pressure", "last", "Fig. 9b: contact pressure after sliding"),
}
"""File stem -> (field, ``"first"`` or ``"last"`` step, title) of the contour figures."""
DEFORMED_FIGURE = "fig10_deformed"
FIELD_UNITS = {"slip": (1e6, "slip (µm)"), "r_n": (1.0, "r_n (N)"), "pressure": (1e-6, "pressure (MPa)")}


def _save(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write_bytes(path, buf.getvalue())


def _case_title(sc: Scenario, k: int) -> str:
    return f"case {k + 1}: μx = {sc.mu_x:g}, μy = {sc.mu_y:g}"


def contour_figure(runs: list[Run], scenarios: list[Scenario], field: str, which: str, title: str, path: Path) -> Path:
    """Three cases side by side on the lower face, one shared colour scale; stick nodes
    drawn as dots, separated nodes as crosses."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    scale, label = FIELD_UNITS[field]
    idx = 0 if which == "first" else -1
    reps = [r.reports[idx] for r in runs]
    gx, gy = (g * 1e3 for g in lower_grid(runs[0].model))
    values = []
    for rep in reps:
        v = node_field(rep, field) * scale
        if field == "pressure":
            v = np.where(rep.node_status == NodeStatus.SEPARATED, np.nan, v)
        values.append(v.reshape(gx.shape))
    lo, hi = np.nanmin(values), np.nanmax(values)
    if not hi > lo:
        lo, hi = lo - 0.5, hi + 0.5
    levels = np.linspace(lo, hi, CONTOUR_LEVELS)
    fig = Figure(figsize=(14, 4.4))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.06, right=0.93, top=0.84, bottom=0.12, wspace=0.15)
    axes = fig.subplots(1, 3, sharey=True)
    for k, (ax, v, rep) in enumerate(zip(axes, values, reps, strict=True)):
        cs = ax.contourf(gx, gy, v, levels=levels, cmap="viridis")
        ax.contour(gx, gy, v, levels=levels[::4], colors="k", linewidths=0.4)
        st = rep.node_status.reshape(gx.shape)
        ax.plot(gx[st == NodeStatus.STICK], gy[st == NodeStatus.STICK], "k.", ms=3, label="stick")
        ax.plot(gx[st == NodeStatus.SEPARATED], gy[st == NodeStatus.SEPARATED], "rx", ms=4, label="separated")
        ax.set_title(_case_title(scenarios[k], k))
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
    axes[0].set_ylabel("y (mm)")
    fig.colorbar(cs, ax=list(axes), label=label, fraction=0.025, pad=0.02)
    step = reps[0].step_index
    push = "" if which == "first" else f", push at {direction_deg(push_direction(scenarios[0])):g}°"
    fig.suptitle(f"{title} (step {step}{push}; lower face, reference coordinates; dots: stick nodes)")
    return _save(fig, path)


def deformed_figure(runs: list[Run], scenarios: list[Scenario], path: Path) -> Path:
    """Fig. 10: deformed blocks after the last step (deformation magnified by
    MAGNIFICATION about the lower-face mean translation) and a true-scale top view of
    the upper- and lower-face centroid paths."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from fe_contact import surface_quads

    model = runs[0].model
    quads = surface_quads(model.mesh)
    X = model.mesh.nodes
    fig = Figure(figsize=(18, 6))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(1, 4, width_ratios=(1, 1, 1, 0.85), wspace=0.12, left=0.0, right=0.98)
    colours = ("tab:blue", "tab:orange", "tab:green")
    for k, run in enumerate(runs):
        rep = run.reports[-1]
        u = rep.displacement
        c = u[model.mesh.lower].mean(axis=0)
        x = (X + c + MAGNIFICATION * (u - c)) * 1e3
        ax = fig.add_subplot(grid[0, k], projection="3d")
        ax.add_collection3d(Poly3DCollection(x[quads], facecolor=colours[k], alpha=0.3, edgecolor="k", linewidth=0.2))
        ref = X[quads[np.all(X[quads][:, :, 2] == 0.0, axis=1)]] * 1e3
        ax.add_collection3d(Poly3DCollection(ref, facecolor="none", edgecolor="0.5", linewidth=0.2))
        lo = np.minimum(x.min(axis=0), X.min(axis=0) * 1e3)
        hi = np.maximum(x.max(axis=0), X.max(axis=0) * 1e3)
        ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(0, hi[2]), xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
        ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], hi[2]), zoom=0.9)
        axis = np.array([x[model.mesh.lower].mean(axis=0), x[model.mesh.upper].mean(axis=0)])
        ax.plot(*axis.T, "k-", lw=2.5, label="lower → upper face centroid")
        for a in (ax.xaxis, ax.yaxis, ax.zaxis):
            a.set_major_locator(MaxNLocator(4))
        if k == 0:
            ax.legend(loc="upper left", fontsize=9)
        ax.view_init(elev=24, azim=-58)
        ax.set_title(f"{_case_title(scenarios[k], k)}\ntwist {math.degrees(rep.twist):.2f}°", fontsize=11)
    ax = fig.add_subplot(grid[0, 3])
    for k, run in enumerate(runs):
        up = np.array([[0.0, 0.0]] + [r.upper_centroid[:2] for r in run.reports]) * 1e3
        lo = np.array([[0.0, 0.0]] + [r.lower_centroid[:2] for r in run.reports]) * 1e3
        if k == 0:
            ax.plot(up[:, 0], up[:, 1], "k--o", ms=3, lw=1, label="upper face (imposed)")
        ax.plot(lo[:, 0], lo[:, 1], "-s", color=colours[k], ms=3, label=f"lower face, case {k + 1}")
    ax.set_aspect("equal")
    ax.yaxis.tick_right()
    ax.yaxis.set_label_position("right")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title="top view: face-centroid paths (true scale)")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.suptitle(f"Fig. 10: deformed mesh after sliding, deformation magnified x{MAGNIFICATION:g} "
                 "about the lower-face mean translation (grey: reference lower face)")
    return _save(fig, path)


def write_figures(runs: list[Run], scenarios: list[Scenario], folder: Path) -> list[Path]:
    """All PNGs of figures 6-10 into ``folder``."""
    folder = prepare_output_dir(folder)
    paths = [contour_figure(runs, scenarios, f, w, t, folder / f"{name}.png") for name, (f, w, t) in FIGURES.items()]
    paths.append(deformed_figure(runs, scenarios, folder / f"{DEFORMED_FIGURE}.png"))
    return paths
