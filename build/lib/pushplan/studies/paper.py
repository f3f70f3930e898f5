"""``pushplan paper``: reproduce the numerical study of sect. 9 of Feng, Hjiaj,
de Saxce, Mroz (2006) with figures 6-10, a quantitative report and VTU files.

The three friction cases (``scenarios/paper_case1..3.toml``) run through
:func:`pushplan.simulate.simulate`; this module turns the results into

``OUT/report.json`` and ``OUT/report.md``
    Per case and step: max slip and where, ``r_n`` and pressure extremes and where,
    stick / slip / separated counts, centroid motions and directions, twist, yaw,
    forces, dissipation, iterations, wall time; and the measured numbers behind
    each claim of sect. 9.1 / 9.2, split into checks with a verdict each.
``OUT/figures/*.png``
    Contour plots on the lower face (reference coordinates, mm) after compression
    (first step) and after the last push, three cases side by side on one shared
    colour scale: slip (fig. 6 / 8), nodal normal reaction ``r_n`` (fig. 7 / 9) and
    contact pressure (``r_n`` / tributary area, fig. 7b / 9b); the magnified
    deformed blocks with a top view of the face-centroid paths (fig. 10).
``OUT/<case>/``
    the outputs of :func:`pushplan.simulate.simulate` (``summary.json``,
    ``fields.npz``, ``recording.rrd``) and ``vtu/step_NN.vtu`` (deformed block,
    nodal fields) with the ``block.pvd`` series.
"""

from __future__ import annotations

import dataclasses
import io
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fe_contact import Model, NodeStatus, StepReport
from fe_contact.model import LOCAL_METHODS

from ..errors import InputError
from ..outputs.atomic import atomic_write_bytes, atomic_write_json, prepare_output_dir
from ..config.scenario import MAX_ELEMENTS, Scenario, load_scenario
from ..run import Run as SimulationResult
from ..run import StepSummary, simulate

CASES = ("paper_case1", "paper_case2", "paper_case3")
from ..resources import scenario_path

SCENARIO_DIR = scenario_path("")
DOCS_FIGURES = Path(__file__).resolve().parents[2] / "docs" / "figures"
MAGNIFICATION = 20.0
"""Factor on the deformation (displacement minus the lower-face mean translation) in fig. 10."""
CONTOUR_LEVELS = 21
RAY_COUNT = 72
RAY_SAMPLES = 200
MONOTONE_TOL = 0.01
"""Largest decrease of slip along a ray from the centre, relative to the max slip, still counted as monotone."""
CLOSE_RTOL = 0.05
"""Relative difference under which values count as "close" / "differ little" / "around" (the paper gives no number)."""
TWIST_ZERO_DEG = 0.01
"""Twist below which the isotropic case counts as untwisted (solver tolerances give ~1e-10 deg)."""
FIGURES = {
    "fig06_slip_compression": ("slip", "first", "Fig. 6: slip after compression"),
    "fig07_rn_compression": ("r_n", "first", "Fig. 7: nodal normal reaction r_n after compression"),
    "fig07b_pressure_compression": ("pressure", "first", "Fig. 7b: contact pressure after compression"),
    "fig08_slip_sliding": ("slip", "last", "Fig. 8: slip after sliding"),
    "fig09_rn_sliding": ("r_n", "last", "Fig. 9: nodal normal reaction r_n after sliding"),
    "fig09b_pressure_sliding": ("pressure", "last", "Fig. 9b: contact pressure after sliding"),
}
FIELD_UNITS = {"slip": (1e6, "slip (µm)"), "r_n": (1.0, "r_n (N)"), "pressure": (1e-6, "pressure (MPa)")}


# ----------------------------------------------------------------------------- runs


def case_scenarios(elements=None, quadrature=None, local_method=None) -> list[Scenario]:
    """The three paper scenarios, with optional mesh / quadrature / local-solver overrides."""
    out = []
    for name in CASES:
        sc = load_scenario(SCENARIO_DIR / f"{name}.toml")
        changes = {}
        if elements is not None:
            elements = tuple(elements)
            if len(elements) != 3 or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in elements):
                raise InputError(f"elements must be three integers >= 1, got {elements!r}")
            if math.prod(elements) > MAX_ELEMENTS:
                raise InputError(f"elements must give at most {MAX_ELEMENTS} hex8, got {elements!r}")
            changes["elements"] = elements
        if quadrature is not None:
            if quadrature not in (2, 3):
                raise InputError(f"quadrature must be 2 or 3, got {quadrature!r}")
            changes["quadrature"] = quadrature
        if local_method is not None:
            changes["solver"] = dataclasses.replace(sc.solver, local_method=local_method)
        out.append(dataclasses.replace(sc, **changes))
    return out


def push_direction(scenario: Scenario) -> np.ndarray:
    """(2,) unit vector of the total in-plane upper-face motion after the first step."""
    d = np.array([[c.dx, c.dy] for c in scenario.commands[1:]]).sum(axis=0)
    norm = float(np.hypot(*d))
    if norm == 0.0:
        raise InputError(f"scenario {scenario.name} has no in-plane push after its first step")
    return d / norm


# ----------------------------------------------------------------------------- measures


def lower_grid(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Reference x and y (m) of the lower-face nodes on their grid, shape (ny+1, nx+1) each."""
    nx, ny, _ = model.mesh.divisions
    X = model.mesh.nodes[model.mesh.lower]
    return X[:, 0].reshape(ny + 1, nx + 1), X[:, 1].reshape(ny + 1, nx + 1)


def node_field(report: StepReport, name: str) -> np.ndarray:
    """(n_lower,) nodal field ``slip`` (m), ``r_n`` (N) or ``pressure`` (Pa)."""
    if name == "slip":
        return report.slip
    if name == "r_n":
        return report.reaction_local[:, 0]
    if name == "pressure":
        return report.pressure
    raise InputError(f"unknown field {name!r} (slip, r_n, pressure)")


def _interpolator(model: Model, values: np.ndarray):
    from scipy.interpolate import RegularGridInterpolator

    gx, gy = lower_grid(model)
    return RegularGridInterpolator((gy[:, 0], gx[0]), values.reshape(gx.shape))


def _edge_position(model: Model, xy: np.ndarray) -> float:
    """0 at the face centre, 1 on its periphery (max of |x|/(lx/2), |y|/(ly/2))."""
    lx, ly, _ = model.mesh.size
    return float(max(abs(xy[0]) / (lx / 2), abs(xy[1]) / (ly / 2)))


def _ray_profiles(model: Model, slip: np.ndarray) -> np.ndarray:
    """Slip sampled on RAY_COUNT rays from the face centre to its edge, shape (rays, samples)."""
    lx, ly, _ = model.mesh.size
    theta = np.linspace(0.0, 2 * np.pi, RAY_COUNT, endpoint=False)
    c, s = np.cos(theta), np.sin(theta)
    with np.errstate(divide="ignore"):
        r_end = np.minimum(np.where(c != 0, lx / 2 / np.abs(c), np.inf), np.where(s != 0, ly / 2 / np.abs(s), np.inf))
    t = np.linspace(0.0, 1.0, RAY_SAMPLES)
    r = r_end[:, None] * t[None, :] * (1 - 1e-12)
    pts = np.stack([r * s[:, None], r * c[:, None]], axis=-1)  # (y, x) order of the interpolator
    return _interpolator(model, slip)(pts)


def _crossing_radius(profile: np.ndarray, radius: np.ndarray, level: float) -> float:
    """First radius where a sampled profile reaches ``level`` (linear between samples)."""
    k = int(np.argmax(profile >= level))
    if profile[k] < level:
        return float("nan")
    if k == 0:
        return float(radius[0])
    f = (level - profile[k - 1]) / (profile[k] - profile[k - 1])
    return float(radius[k - 1] + f * (radius[k] - radius[k - 1]))


def slip_shape(model: Model, slip: np.ndarray) -> dict:
    """Shape measures of a compression slip field.

    ``y_over_x``: mean slip at (0, +-ly/2) over mean slip at (+-lx/2, 0);
    ``iso_aspect_x_over_y``: extent along x over extent along y of the slip
    iso-line at half the smaller of those two edge values (> 1: elongated along x);
    ``worst_ray_decrease``: largest drop of slip along any ray from the centre,
    relative to the max slip (0 for a field growing monotonically outward).
    """
    lx, ly, _ = model.mesh.size
    f = _interpolator(model, slip)
    eps = 1e-12
    s_x = float(f([[0.0, lx / 2 * (1 - eps)], [0.0, -lx / 2 * (1 - eps)]]).mean())
    s_y = float(f([[ly / 2 * (1 - eps), 0.0], [-ly / 2 * (1 - eps), 0.0]]).mean())
    level = 0.5 * min(s_x, s_y)
    t = np.linspace(0.0, 1.0, 4 * RAY_SAMPLES) * (1 - eps)
    rx = [_crossing_radius(f(np.stack([0 * t, sg * lx / 2 * t], -1)), lx / 2 * t, level) for sg in (1, -1)]
    ry = [_crossing_radius(f(np.stack([sg * ly / 2 * t, 0 * t], -1)), ly / 2 * t, level) for sg in (1, -1)]
    prof = _ray_profiles(model, slip)
    drop = np.maximum.accumulate(prof, axis=1) - prof
    smax = float(slip.max())
    return {
        "slip_edge_x": s_x,
        "slip_edge_y": s_y,
        "y_over_x": s_y / s_x if s_x > 0 else float("inf"),
        "iso_level": level,
        "iso_radius_x": float(np.mean(rx)),
        "iso_radius_y": float(np.mean(ry)),
        "iso_aspect_x_over_y": float(np.mean(rx) / np.mean(ry)),
        "worst_ray_decrease": float(drop.max() / smax) if smax > 0 else 0.0,
    }


def _extreme(model: Model, values: np.ndarray, mask: np.ndarray, fn) -> tuple[float, list[float]]:
    idx = np.flatnonzero(mask)
    k = idx[fn(values[idx])]
    return float(values[k]), model.mesh.nodes[model.mesh.lower[k], :2].tolist()


def step_record(model: Model, report: StepReport, push: np.ndarray) -> dict:
    """:func:`pushplan.simulate.step_summary` plus where the extremes occur (reference
    x, y in m), ``r_n`` extremes and the centroid motion directions (deg)."""
    rec = StepSummary.from_report(report).to_dict()
    contact = report.node_status != NodeStatus.SEPARATED
    every = np.ones_like(contact)
    rec["max_slip"], rec["max_slip_at"] = _extreme(model, report.slip, every, np.argmax)
    rn = report.reaction_local[:, 0]
    rec["r_n_max"], rec["r_n_max_at"] = _extreme(model, rn, every, np.argmax)
    rec["r_n_min"], rec["r_n_min_at"] = _extreme(model, rn, every, np.argmin)
    rec["pressure_max_at"] = rec["pressure_min_at"] = None
    if contact.any():
        rec["pressure_max"], rec["pressure_max_at"] = _extreme(model, report.pressure, contact, np.argmax)
        rec["pressure_min"], rec["pressure_min_at"] = _extreme(model, report.pressure, contact, np.argmin)
    up, lo = report.upper_centroid[:2], report.lower_centroid[:2]
    moved = np.hypot(*up) > 0
    rec["push_direction_deg"] = math.degrees(math.atan2(push[1], push[0]))
    rec["upper_direction_deg"] = math.degrees(math.atan2(up[1], up[0])) if moved else None
    rec["lower_direction_deg"] = math.degrees(math.atan2(lo[1], lo[0])) if moved else None
    return rec


def _spread(values) -> float:
    v = np.asarray(values, dtype=float)
    return float((v.max() - v.min()) / abs(v.mean()))


def _check(text: str, holds) -> dict:
    return {"check": text, "holds": bool(holds)}


def _field_extremes(model: Model, reports: list[StepReport], name: str, push: np.ndarray) -> dict:
    """Per case: max / min of a lower-face field, where, and the front/back mean ratio
    along ``push``; spreads across cases (relative to the mean, and the min's spread
    relative to the mean max).  Pressure is taken over nodes in contact only."""
    xy = model.mesh.nodes[model.mesh.lower, :2]
    s = xy @ push
    rows = []
    for rep in reports:
        v = node_field(rep, name)
        mask = rep.node_status != NodeStatus.SEPARATED if name == "pressure" else np.ones(v.shape, bool)
        vmax, at_max = _extreme(model, v, mask, np.argmax)
        vmin, at_min = _extreme(model, v, mask, np.argmin)
        rows.append({
            "max": vmax, "max_at": at_max, "max_edge_position": _edge_position(model, at_max),
            "max_along_push": float(np.dot(at_max, push)),
            "min": vmin, "min_at": at_min, "min_edge_position": _edge_position(model, at_min),
            "min_along_push": float(np.dot(at_min, push)),
            "front_over_back_mean": float(v[mask & (s > 0)].mean() / v[mask & (s < 0)].mean()),
        })
    maxima = [r["max"] for r in rows]
    return {
        "cases": rows,
        "max_spread": _spread(maxima),
        "min_spread": _spread([r["min"] for r in rows]),
        "min_spread_of_max": float(np.ptp([r["min"] for r in rows]) / np.mean(maxima)),
    }


def _centre_over_max(model: Model, values: np.ndarray) -> float:
    """Value at the node nearest the face centre over the field's max."""
    gx, gy = lower_grid(model)
    centre = int(np.argmin(np.hypot(gx, gy)))
    return float(values[centre] / values.max())


def measure_claims(runs: list[SimulationResult], push: np.ndarray) -> dict:
    """Numbers behind the claims of sect. 9.1 / 9.2, split into checks with a verdict each.

    Returns
    -------
    dict
        Per claim: ``paper`` (its wording), ``checks`` (list of ``{check, holds}``),
        ``holds`` (all checks hold) and the measured numbers.
    """
    model = runs[0].model
    lx, ly, _ = model.mesh.size
    gx, gy = lower_grid(model)
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    centre = int(np.argmin(np.hypot(xy[:, 0], xy[:, 1])))
    on_edge = np.isclose(np.abs(xy[:, 0]), lx / 2) | np.isclose(np.abs(xy[:, 1]), ly / 2)
    first = [r.reports[0] for r in runs]
    last = [r.reports[-1] for r in runs]
    claims = {}

    c1 = []
    for rep in first:
        stick = rep.node_status == NodeStatus.STICK
        c1.append({
            "centre_stick": bool(stick[centre]),
            "n_stick": int(stick.sum()),
            "stick_on_periphery": int((stick & on_edge).sum()),
            "stick_centroid": xy[stick].mean(axis=0).tolist() if stick.any() else None,
            **slip_shape(model, rep.slip),
        })
    aspect = [c["iso_aspect_x_over_y"] for c in c1]
    ratio = [c["y_over_x"] for c in c1]
    claims["1_compression_slip"] = {
        "paper": "stick zone around the base centre; slip grows monotonically toward the periphery; iso-lines "
                 "circular (isotropic), elliptic like the friction criterion (anisotropic), flat ellipses for case 3; "
                 "larger tangential displacement along y, the low-friction direction",
        "cases": c1,
        "checks": [
            _check("the centre node sticks, no periphery node sticks", all(c["centre_stick"] and not c["stick_on_periphery"] for c in c1)),
            _check(f"slip never drops by more than {MONOTONE_TOL:.0%} of its max along {RAY_COUNT} rays from the centre",
                   all(c["worst_ray_decrease"] <= MONOTONE_TOL for c in c1)),
            _check(f"case 1 iso-line circular: aspect x/y within {CLOSE_RTOL:.0%} of 1 (measured {aspect[0]:.3f})",
                   abs(aspect[0] - 1) < CLOSE_RTOL),
            _check(f"case 2, 3 iso-lines elliptic, flat in y like the friction ellipse (semi-axes mu_x, mu_y), flatter "
                   f"for case 3: 1 < aspect x/y {aspect[1]:.2f} < {aspect[2]:.2f}", 1 < aspect[1] < aspect[2]),
            _check(f"slip larger along y: slip at y-edge / x-edge {ratio[0]:.2f}, {ratio[1]:.2f}, {ratio[2]:.2f} "
                   "(1, then growing with mu_x / mu_y)", abs(ratio[0] - 1) < CLOSE_RTOL and 1 < ratio[1] < ratio[2]),
        ],
    }

    rn1 = _field_extremes(model, first, "r_n", push)
    p1 = _field_extremes(model, first, "pressure", push)
    rn1["centre_over_max"] = [_centre_over_max(model, node_field(rep, "r_n")) for rep in first]
    p1["centre_over_max"] = [_centre_over_max(model, node_field(rep, "pressure")) for rep in first]
    claims["2_compression_normal_reaction"] = {
        "paper": "largest r_n around the base centre, not changing notably with friction; minimum at the periphery",
        "r_n": rn1, "pressure": p1,
        "checks": [
            _check("r_n global max in the inner half of the face (edge position <= 0.5); positions "
                   + ", ".join(f"{r['max_edge_position']:.2f}" for r in rn1["cases"]),
                   all(r["max_edge_position"] <= 0.5 for r in rn1["cases"])),
            _check(f"r_n at the centre within {CLOSE_RTOL:.0%} of the global max: centre / max "
                   + ", ".join(f"{b:.3f}" for b in rn1["centre_over_max"]),
                   min(rn1["centre_over_max"]) > 1 - CLOSE_RTOL),
            _check("r_n min on the periphery", all(r["min_edge_position"] > 1 - 1e-9 for r in rn1["cases"])),
            _check(f"r_n max differs little across cases: spread {rn1['max_spread']:.1%} < {CLOSE_RTOL:.0%}",
                   rn1["max_spread"] < CLOSE_RTOL),
            _check("(not in the paper) pressure r_n / area peaks on the periphery; centre / max "
                   + ", ".join(f"{b:.3f}" for b in p1["centre_over_max"]),
                   all(r["max_edge_position"] > 1 - 1e-9 for r in p1["cases"])),
        ],
    }

    front_corner = np.array([np.sign(push[0]) * lx / 2, np.sign(push[1]) * ly / 2])
    h = math.hypot(lx / model.mesh.divisions[0], ly / model.mesh.divisions[1])
    c3 = []
    for rep in last:
        vmax, at = _extreme(model, rep.slip, np.ones(rep.slip.shape, bool), np.argmax)
        c3.append({
            "max_slip": vmax, "max_slip_at": at,
            "distance_to_front_corner": float(np.hypot(*(np.asarray(at) - front_corner))),
            "lower_centroid_x": float(rep.lower_centroid[0]),
            "lower_centroid_y": float(rep.lower_centroid[1]),
        })
    c12 = abs(c3[0]["max_slip"] - c3[1]["max_slip"]) / c3[0]["max_slip"]
    y = [c["lower_centroid_y"] for c in c3]
    claims["3_sliding_slip"] = {
        "paper": "max slip at the front corner; case 1 and case 2 max slips close; larger y displacement for case 3",
        "cases": c3, "case1_case2_relative_difference": c12,
        "checks": [
            _check(f"max slip within one element diagonal ({h * 1e3:.2f} mm) of the front corner; distances "
                   + ", ".join(f"{c['distance_to_front_corner'] * 1e3:.2f} mm" for c in c3),
                   all(c["distance_to_front_corner"] <= h for c in c3)),
            _check(f"case 1 and case 2 max slips differ by {c12:.2%} < {CLOSE_RTOL:.0%}", c12 < CLOSE_RTOL),
            _check("case 3 lower face moves furthest in y: " + ", ".join(f"{v * 1e3:.4f}" for v in y) + " mm",
                   y[2] > max(y[0], y[1])),
        ],
    }

    rn5 = _field_extremes(model, last, "r_n", push)
    p5 = _field_extremes(model, last, "pressure", push)
    claims["4_sliding_normal_reaction"] = {
        "paper": "r_n max in the front area, min in the back area; max and min very close for all cases",
        "r_n": rn5, "pressure": p5,
        "tangential_force": [float(math.hypot(*rep.tangential_force)) for rep in last],
        "checks": [
            _check("r_n max ahead of the centre, r_n min behind it (along the push)",
                   all(r["max_along_push"] > 0 > r["min_along_push"] for r in rn5["cases"])),
            _check("pressure max ahead of the centre, pressure min behind it",
                   all(r["max_along_push"] > 0 > r["min_along_push"] for r in p5["cases"])),
            _check(f"r_n max very close across cases: spread {rn5['max_spread']:.1%} < {CLOSE_RTOL:.0%}",
                   rn5["max_spread"] < CLOSE_RTOL),
            _check(f"r_n min very close across cases: spread {rn5['min_spread_of_max']:.1%} of the mean max "
                   f"< {CLOSE_RTOL:.0%}", rn5["min_spread_of_max"] < CLOSE_RTOL),
        ],
    }

    c5 = []
    for rep in last:
        lo = rep.lower_centroid[:2]
        c5.append({
            "twist_deg": math.degrees(rep.twist),
            "lower_direction_deg": math.degrees(math.atan2(lo[1], lo[0])),
            "lag_direction_deg": math.degrees(math.atan2(rep.lag[1], rep.lag[0])),
            "lower_yaw_deg": math.degrees(rep.lower_yaw),
        })
    tw = [abs(c["twist_deg"]) for c in c5]
    claims["5_twist"] = {
        "paper": "isotropic: lower and upper faces move in the same direction, no twist; anisotropic: different "
                 "directions, the block twists, more for case 3",
        "cases": c5,
        "checks": [
            _check(f"case 1 twist {tw[0]:.2g}° < {TWIST_ZERO_DEG}°", tw[0] < TWIST_ZERO_DEG),
            _check(f"case 2, 3 twist {tw[1]:.3f}°, {tw[2]:.3f}° > {TWIST_ZERO_DEG}°", min(tw[1:]) > TWIST_ZERO_DEG),
            _check("twist larger for case 3 than case 2", tw[2] > tw[1]),
        ],
    }
    for c in claims.values():
        c["holds"] = all(k["holds"] for k in c["checks"])
    return claims


# ----------------------------------------------------------------------------- VTU


def _atomic_meshio_write(path: Path, mesh) -> None:
    """meshio writes to a path only: write in a scratch folder, then copy atomically."""
    import meshio

    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(scratch) / path.name
        meshio.write(tmp, mesh, file_format="vtu")
        atomic_write_bytes(path, tmp.read_bytes())


def write_vtu(model: Model, reports: list[StepReport], folder: Path) -> list[Path]:
    """One VTU per step (points at the deformed positions, m) and a ``block.pvd`` series.

    Point data: ``displacement`` (m); on the lower face, zero elsewhere:
    ``reaction`` (world, N), ``r_n`` (N), ``pressure`` (Pa), ``slip`` and
    ``slip_path`` (m), ``gap`` (m); ``contact_status`` 0 stick / 1 slip / 2
    separated / -1 not a contact node.
    """
    import meshio

    folder = prepare_output_dir(folder)
    mesh = model.mesh
    lower = mesh.lower

    def on_face(values, dtype=float, fill=0.0):
        a = np.full((mesh.n_nodes,) + np.shape(values)[1:], fill, dtype=dtype)
        a[lower] = values
        return a

    paths = []
    for rep in reports:
        point_data = {
            "displacement": rep.displacement,
            "reaction": on_face(rep.reaction_world),
            "r_n": on_face(rep.reaction_local[:, 0]),
            "pressure": on_face(rep.pressure),
            "slip": on_face(rep.slip),
            "slip_path": on_face(rep.slip_path),
            "gap": on_face(rep.gap),
            "contact_status": on_face(rep.node_status, dtype=np.int32, fill=-1),
        }
        block = meshio.Mesh(mesh.nodes + rep.displacement, [("hexahedron", mesh.elements)], point_data=point_data)
        path = folder / f"step_{rep.step_index:02d}.vtu"
        _atomic_meshio_write(path, block)
        paths.append(path)
    entries = "\n".join(f'    <DataSet timestep="{r.step_index}" file="{p.name}"/>' for r, p in zip(reports, paths))
    pvd = f'<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n{entries}\n  </Collection>\n</VTKFile>\n'
    atomic_write_bytes(folder / "block.pvd", pvd.encode())
    return paths


# ----------------------------------------------------------------------------- figures


def _save(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write_bytes(path, buf.getvalue())


def _case_title(sc: Scenario, k: int) -> str:
    return f"case {k + 1}: μx = {sc.mu_x:g}, μy = {sc.mu_y:g}"


def contour_figure(runs: list[SimulationResult], scenarios: list[Scenario], field: str, which: str, title: str, path: Path) -> Path:
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
    for k, (ax, v, rep) in enumerate(zip(axes, values, reps)):
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
    push = "" if which == "first" else f", push at {math.degrees(math.atan2(*push_direction(scenarios[0])[::-1])):g}°"
    fig.suptitle(f"{title} (step {step}{push}; lower face, reference coordinates; dots: stick nodes)")
    return _save(fig, path)


def deformed_figure(runs: list[SimulationResult], scenarios: list[Scenario], path: Path) -> Path:
    """Fig. 10: deformed blocks after the last step (deformation magnified by
    MAGNIFICATION about the lower-face mean translation) and a true-scale top view of
    the upper- and lower-face centroid paths."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from fe_contact.mesh import surface_quads

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


def write_figures(runs: list[SimulationResult], scenarios: list[Scenario], folder: Path) -> list[Path]:
    """All PNGs of figures 6-10 into ``folder``."""
    folder = prepare_output_dir(folder)
    paths = [contour_figure(runs, scenarios, f, w, t, folder / f"{name}.png") for name, (f, w, t) in FIGURES.items()]
    paths.append(deformed_figure(runs, scenarios, folder / "fig10_deformed.png"))
    return paths


# ----------------------------------------------------------------------------- report


def _mm(xy) -> str:
    return "-" if xy is None else f"({xy[0] * 1e3:+.1f}, {xy[1] * 1e3:+.1f})"


def report_markdown(report: dict) -> str:
    """Human-readable version of ``report.json``."""
    run = report["run"]
    lines = [
        "# Reproduction of Feng, Hjiaj, de Saxcé, Mróz (2006), sect. 9",
        "",
        f"Mesh {run['elements']} hex8, {run['quadrature']}^3 Gauss points, local solver `{run['local_method']}`; "
        f"wall time {run['wall_time_s']:.1f} s (simulation {run['simulate_s']:.1f} s, figures {run['figures_s']:.1f} s).",
        "Positions are reference coordinates of lower-face nodes in mm; the push is along "
        f"{run['push_direction_deg']:.1f}°.",
        "",
        "`r_n` is the nodal normal reaction (N), what the paper plots; the pressure is `r_n` / tributary area (MPa). "
        "Corner and edge nodes carry 1/4 and 1/2 of an interior tributary area, so `r_n` is smallest on the periphery "
        "by construction; the pressure shows where the contact is actually loaded hardest.",
        "",
    ]
    for case in report["cases"]:
        sc = case["scenario"]
        lines += [
            f"## {case['name']}: mu_x = {sc['friction']['mu_x']}, mu_y = {sc['friction']['mu_y']} "
            f"({case['status']}, {case['elapsed_s']:.1f} s)",
            "",
            "| step | max slip µm @ | r_n max N @ | r_n min N @ | p max MPa @ | p min MPa @ | stick/slip/sep "
            "| lower centroid mm | dir ° | twist ° | yaw ° | N kN | T kN | dissip. J | newton/local | s |",
            "|---" * 16 + "|",
        ]
        if case["failure"]:
            lines[-2:-2] = [f"Failed at step {case['failure']['step']} ({case['failure']['status']}): "
                            f"{case['failure']['message']}", ""]
        for s in case["steps"]:
            lo = s["lower_centroid"]
            d = "-" if s["lower_direction_deg"] is None else f"{s['lower_direction_deg']:.2f}"
            lines.append(
                f"| {s['step']} | {s['max_slip'] * 1e6:.2f} {_mm(s['max_slip_at'])} "
                f"| {s['r_n_max']:.0f} {_mm(s['r_n_max_at'])} | {s['r_n_min']:.0f} {_mm(s['r_n_min_at'])} "
                f"| {s['pressure_max'] / 1e6:.0f} {_mm(s['pressure_max_at'])} "
                f"| {s['pressure_min'] / 1e6:.0f} {_mm(s['pressure_min_at'])} "
                f"| {s['n_stick']}/{s['n_slip']}/{s['n_separated']} | ({lo[0] * 1e3:.4f}, {lo[1] * 1e3:.4f}) | {d} "
                f"| {s['twist_deg']:.3f} | {s['lower_yaw_deg']:.4f} | {s['normal_force'] / 1e3:.1f} "
                f"| {math.hypot(*s['tangential_force']) / 1e3:.1f} | {s['dissipation']:.3f} "
                f"| {s['newton_iterations']}/{s['contact_iterations']} | {s['wall_time_s']:.2f} |"
            )
        lines.append("")
    claims = report.get("claims")
    if claims:
        lines += ["## Claims of sect. 9.1 / 9.2, measured", "", "[x]: the check holds on this run; [ ]: it does not.", ""]
        for key, c in claims.items():
            lines += [f"### {key}: {'holds' if c['holds'] else 'does NOT fully hold'}", "", f"Paper: {c['paper']}.", ""]
            lines += [f"- [{'x' if k['holds'] else ' '}] {k['check']}" for k in c["checks"]]
            lines += [""] + [f"- {line}" for line in _claim_lines(key, c)]
            lines.append("")
    lines += ["## Files", ""] + [f"- `{p}`" for p in report["files"]] + [""]
    return "\n".join(lines)


def _claim_lines(key: str, c: dict) -> list[str]:
    """Short numeric lines for one claim in ``report.md``."""
    if key.startswith("1"):
        return [f"case {k + 1}: stick nodes {x['n_stick']} (centre sticks: {x['centre_stick']}, on periphery: "
                f"{x['stick_on_periphery']}), slip at y-edge / x-edge {x['y_over_x']:.2f}, iso-line aspect x/y "
                f"{x['iso_aspect_x_over_y']:.2f} at {x['iso_level'] * 1e6:.2f} µm, worst decrease along a ray "
                f"{x['worst_ray_decrease']:.2%}" for k, x in enumerate(c["cases"])]
    if key.startswith(("2", "4")):
        out = []
        for name, unit, f in (("r_n", "N", 1.0), ("pressure", "MPa", 1e-6)):
            d = c[name]
            for k, x in enumerate(d["cases"]):
                out.append(f"{name} case {k + 1}: max {x['max'] * f:.0f} {unit} at {_mm(x['max_at'])}, "
                           f"min {x['min'] * f:.0f} {unit} at {_mm(x['min_at'])}, front/back mean {x['front_over_back_mean']:.3f}")
            out.append(f"{name} spread across cases: max {d['max_spread']:.1%}, min {d['min_spread']:.1%} "
                       f"({d['min_spread_of_max']:.1%} of the mean max)")
        if "tangential_force" in c:
            out.append("total friction force: " + ", ".join(f"{t / 1e3:.1f} kN" for t in c["tangential_force"]))
        return out
    if key.startswith("3"):
        return [f"case {k + 1}: max slip {x['max_slip'] * 1e3:.4f} mm at {_mm(x['max_slip_at'])} "
                f"({x['distance_to_front_corner'] * 1e3:.2f} mm from the front corner), lower centroid "
                f"({x['lower_centroid_x'] * 1e3:.4f}, {x['lower_centroid_y'] * 1e3:.4f}) mm" for k, x in enumerate(c["cases"])] + [
            f"case 1 vs case 2 max slip: {c['case1_case2_relative_difference']:.2%}"]
    return [f"case {k + 1}: twist {x['twist_deg']:.3f}°, lower-face direction {x['lower_direction_deg']:.2f}°, "
            f"shear (lag) direction {x['lag_direction_deg']:.2f}°, lower-face yaw {x['lower_yaw_deg']:.4f}°"
            for k, x in enumerate(c["cases"])]


def run_paper(out, elements=None, quadrature=None, local_method=None, docs_dir=None, progress: bool = False) -> dict:
    """Run the three cases into ``out`` and write figures, VTU files and the report.

    Parameters
    ----------
    out : path
        Output folder (created if needed).
    elements : (3,) int, optional
        Mesh override ``(nx, ny, nz)``; default the scenarios' (the paper's 20 x 20 x 5).
    quadrature : int, optional
        Gauss points per direction override (1, 2 or 3).
    local_method : str, optional
        Local contact solver override (``"uzawa"``, as in the paper, or ``"newton"``).
    docs_dir : path, optional
        Also copy the PNGs there.
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    dict
        The content of ``report.json``; ``report["status"]`` is ``"completed"`` or ``"failed"``.
    """
    t0 = time.perf_counter()
    scenarios = case_scenarios(elements, quadrature, local_method)
    out = prepare_output_dir(out)
    push = push_direction(scenarios[0])
    runs = []
    for sc in scenarios:
        runs.append(simulate(sc, prepare_output_dir(out / sc.name), progress=progress))
    t_sim = time.perf_counter() - t0
    completed = all(r.completed for r in runs)
    files = [f"{sc.name}/{f}" for sc in scenarios for f in ("summary.json", "fields.npz", "recording.rrd")
             if (out / sc.name / f).exists()]
    cases = []
    for sc, run in zip(scenarios, runs):
        good = [r for r in run.reports if r.converged]
        cases.append({
            "name": sc.name, "scenario": run.summary.scenario, "status": run.summary.status.value,
            "failure": run.summary.to_dict()["failure"], "elapsed_s": run.summary.elapsed_s,
            "steps": [step_record(run.model, r, push) for r in good],
        })
        if good:
            vtu = write_vtu(run.model, good, out / sc.name / "vtu")
            files += [f"{sc.name}/vtu/{p.name}" for p in vtu] + [f"{sc.name}/vtu/block.pvd"]
    t1 = time.perf_counter()
    claims = None
    if completed:
        claims = measure_claims(runs, push)
        figs = write_figures(runs, scenarios, out / "figures")
        files += [f"figures/{p.name}" for p in figs]
        if docs_dir is not None:
            docs = prepare_output_dir(docs_dir)
            for p in figs:
                atomic_write_bytes(docs / p.name, p.read_bytes())
    t_fig = time.perf_counter() - t1
    report = {
        "status": "completed" if completed else "failed",
        "run": {
            "elements": list(scenarios[0].elements), "quadrature": scenarios[0].quadrature,
            "local_method": scenarios[0].solver.local_method, "simulate_s": t_sim, "figures_s": t_fig,
            "wall_time_s": time.perf_counter() - t0, "magnification": MAGNIFICATION,
            "push_direction_deg": math.degrees(math.atan2(push[1], push[0])),
        },
        "cases": cases,
        "claims": claims,
        "files": files + ["report.json", "report.md"],
    }
    atomic_write_json(out / "report.json", report)
    atomic_write_bytes(out / "report.md", report_markdown(report).encode())
    return report


# ----------------------------------------------------------------------------- CLI


def cmd_paper(args) -> int:
    """``pushplan paper``: exit 0, or 3 when a case's solver fails (report keeps the finished steps)."""
    from ..errors import EXIT_SOLVER_FAILURE

    report = run_paper(
        args.out, elements=args.elements, quadrature=args.quadrature, local_method=args.local_method,
        docs_dir=DOCS_FIGURES if args.docs else None, progress=not args.quiet,
    )
    for case in report["cases"]:
        s = case["steps"][-1] if case["steps"] else None
        if s is not None:
            print(f"{case['name']}: {case['status']}, {case['elapsed_s']:.1f} s, max slip {s['max_slip'] * 1e3:.4f} mm, "
                  f"twist {s['twist_deg']:.3f}°, lower-face direction {s['lower_direction_deg']:.2f}°")
    for key, c in (report["claims"] or {}).items():
        print(f"claim {key}: {'holds' if c['holds'] else 'does NOT fully hold'}")
        for check in c["checks"]:
            if not check["holds"]:
                print(f"    not: {check['check']}")
    print(f"wrote {Path(args.out) / 'report.md'} ({report['run']['wall_time_s']:.1f} s)")
    if report["status"] != "completed":
        failed = [c["name"] for c in report["cases"] if c["status"] != "completed"]
        print(f"pushplan: solver failure in {', '.join(failed)}", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def register(subparsers) -> None:
    """Add the ``paper`` subcommand."""
    p = subparsers.add_parser("paper", help="reproduce the paper's sect. 9 (figures 6-10, report, VTU)")
    p.add_argument("--out", default="out/paper", help="output folder (default: out/paper)")
    p.add_argument("--elements", nargs=3, type=int, metavar=("NX", "NY", "NZ"),
                   help="mesh override for coarse runs (default: the paper's 20 20 5)")
    p.add_argument("--quadrature", type=int, choices=(2, 3), help="Gauss points per direction (default: 3)")
    p.add_argument("--local-method", choices=LOCAL_METHODS,
                   help="local contact solver (default: the scenarios'; the paper's is uzawa)")
    p.add_argument("--docs", action="store_true", help=f"also copy the PNGs to {DOCS_FIGURES}")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_paper)

