"""The claims of sect. 9.1 / 9.2 of Feng, Hjiaj, de Saxce, Mroz (2006), measured on
the three paper cases: one function per claim, each returning a :class:`Claim` (the
paper's wording, the measured numbers, and checks with a verdict each).

Claims 1 and 2 are read after the compression (first step), 3 to 5 after the last
push.  Positions are reference coordinates of lower-face nodes (m); "edge position"
is 0 at the face centre and 1 on its periphery.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fe_contact import Model, NodeStatus, StepReport

from ..run import Run
from .paper_cases import extreme, lower_grid, node_field

RAY_COUNT = 72
RAY_SAMPLES = 200
MONOTONE_TOL = 0.01
"""Largest decrease of slip along a ray from the centre, relative to the max slip, still counted as monotone."""
CLOSE_RTOL = 0.05
"""Relative difference under which values count as "close" / "differ little" / "around" (the paper gives no number)."""
TWIST_ZERO_DEG = 0.01
"""Twist below which the isotropic case counts as untwisted (solver tolerances give ~1e-10 deg)."""


@dataclass(frozen=True)
class Check:
    """One verifiable statement of a claim and whether it holds on this run."""

    text: str
    holds: bool

    def to_dict(self) -> dict:
        return {"check": self.text, "holds": bool(self.holds)}


@dataclass(frozen=True)
class Claim:
    """A claim of the paper: ``key`` (``"1_compression_slip"``, ...), its wording,
    the measured numbers (``report.json`` tables) and its checks."""

    key: str
    paper: str
    measures: dict
    checks: tuple[Check, ...]

    @property
    def holds(self) -> bool:
        return all(c.holds for c in self.checks)

    @property
    def failed_checks(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if not c.holds)

    def to_dict(self) -> dict:
        """``{paper, <measures>, checks: [{check, holds}], holds}``."""
        return {"paper": self.paper, **self.measures, "checks": [c.to_dict() for c in self.checks],
                "holds": self.holds}


# ---- measures on the lower face ---------------------------------------------------


def _interpolator(model: Model, values: np.ndarray):
    from scipy.interpolate import RegularGridInterpolator

    gx, gy = lower_grid(model)
    return RegularGridInterpolator((gy[:, 0], gx[0]), values.reshape(gx.shape))


def _edge_position(model: Model, xy) -> float:
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
        "iso_aspect_x_over_y": _ratio(float(np.mean(rx)), float(np.mean(ry))),
        "worst_ray_decrease": float(drop.max() / smax) if smax > 0 else 0.0,
    }


def _ratio(a: float, b: float) -> float:
    """``a / b`` without numpy's RuntimeWarning: nan when either extent is unknown (a
    profile that never reaches the level), inf for a zero ``b``."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return float("nan")
    return a / b if b != 0 else float("inf")


def _spread(values) -> float:
    v = np.asarray(values, dtype=float)
    return float((v.max() - v.min()) / abs(v.mean()))


def field_extremes(model: Model, reports: list[StepReport], name: str, push: np.ndarray) -> dict:
    """Per case: max / min of a lower-face field, where, and the front/back mean ratio
    along ``push``; spreads across cases (relative to the mean, and the min's spread
    relative to the mean max).  Pressure is taken over nodes in contact only."""
    s = model.mesh.nodes[model.mesh.lower, :2] @ push
    rows = []
    for rep in reports:
        v = node_field(rep, name)
        mask = rep.node_status != NodeStatus.SEPARATED if name == "pressure" else np.ones(v.shape, bool)
        vmax, at_max = extreme(model, v, mask, np.argmax)
        vmin, at_min = extreme(model, v, mask, np.argmin)
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


def _joined(values, fmt: str) -> str:
    return ", ".join(format(v, fmt) for v in values)


# ---- the claims ---------------------------------------------------------------------


def claim_compression_slip(model: Model, first: list[StepReport]) -> Claim:
    """Claim 1: stick zone at the centre, slip growing outward, iso-lines shaped by the friction ellipse."""
    lx, ly, _ = model.mesh.size
    gx, gy = lower_grid(model)
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    centre = int(np.argmin(np.hypot(xy[:, 0], xy[:, 1])))
    on_edge = np.isclose(np.abs(xy[:, 0]), lx / 2) | np.isclose(np.abs(xy[:, 1]), ly / 2)
    cases = []
    for rep in first:
        stick = rep.node_status == NodeStatus.STICK
        cases.append({
            "centre_stick": bool(stick[centre]),
            "n_stick": int(stick.sum()),
            "stick_on_periphery": int((stick & on_edge).sum()),
            "stick_centroid": xy[stick].mean(axis=0).tolist() if stick.any() else None,
            **slip_shape(model, rep.slip),
        })
    aspect = [c["iso_aspect_x_over_y"] for c in cases]
    ratio = [c["y_over_x"] for c in cases]
    return Claim(
        "1_compression_slip",
        "stick zone around the base centre; slip grows monotonically toward the periphery; iso-lines "
        "circular (isotropic), elliptic like the friction criterion (anisotropic), flat ellipses for case 3; "
        "larger tangential displacement along y, the low-friction direction",
        {"cases": cases},
        (
            Check("stick zone: criterion the centre node sticks and no periphery node sticks",
                  all(c["centre_stick"] and not c["stick_on_periphery"] for c in cases)),
            Check(f"largest slip drop along {RAY_COUNT} rays from the centre: measured "
                  + _joined([c["worst_ray_decrease"] for c in cases], ".1%") + f" of the max, criterion <= "
                  f"{MONOTONE_TOL:.0%}", all(c["worst_ray_decrease"] <= MONOTONE_TOL for c in cases)),
            Check(f"case 1 iso-line aspect x/y: measured {aspect[0]:.3f}, criterion within {CLOSE_RTOL:.0%} of 1 "
                  "(circular)",
                  abs(aspect[0] - 1) < CLOSE_RTOL),
            Check(f"case 2, 3 iso-line aspect x/y: measured {aspect[1]:.2f}, {aspect[2]:.2f}, criterion 1 < case 2 "
                  "< case 3 (flat in y like the friction ellipse, flatter for case 3)", 1 < aspect[1] < aspect[2]),
            Check(f"slip at y-edge / x-edge: measured {_joined(ratio, '.2f')}, criterion case 1 within "
                  f"{CLOSE_RTOL:.0%} of 1, then 1 < case 2 < case 3 (growing with mu_x / mu_y)", abs(ratio[0] - 1) < CLOSE_RTOL and 1 < ratio[1] < ratio[2]),
        ),
    )


def claim_compression_normal_reaction(model: Model, first: list[StepReport], push: np.ndarray) -> Claim:
    """Claim 2: ``r_n`` largest around the centre, alike across cases, smallest on the periphery."""
    rn = field_extremes(model, first, "r_n", push)
    p = field_extremes(model, first, "pressure", push)
    rn["centre_over_max"] = [_centre_over_max(model, node_field(rep, "r_n")) for rep in first]
    p["centre_over_max"] = [_centre_over_max(model, node_field(rep, "pressure")) for rep in first]
    return Claim(
        "2_compression_normal_reaction",
        "largest r_n around the base centre, not changing notably with friction; minimum at the periphery",
        {"r_n": rn, "pressure": p},
        (
            Check("r_n global max edge position: measured "
                  + _joined([r["max_edge_position"] for r in rn["cases"]], ".2f")
                  + ", criterion <= 0.5 (inner half of the face)",
                  all(r["max_edge_position"] <= 0.5 for r in rn["cases"])),
            Check("r_n at the centre / global max: measured " + _joined(rn["centre_over_max"], ".3f")
                  + f", criterion > {1 - CLOSE_RTOL:.2f}", min(rn["centre_over_max"]) > 1 - CLOSE_RTOL),
            Check("r_n min: criterion on the periphery", all(r["min_edge_position"] > 1 - 1e-9 for r in rn["cases"])),
            Check(f"r_n max spread across cases: measured {rn['max_spread']:.1%}, criterion < {CLOSE_RTOL:.0%}",
                  rn["max_spread"] < CLOSE_RTOL),
            Check("(not in the paper) pressure r_n / area: centre / max measured "
                  + _joined(p["centre_over_max"], ".3f") + ", criterion peak on the periphery", all(r["max_edge_position"] > 1 - 1e-9 for r in p["cases"])),
        ),
    )


def claim_sliding_slip(model: Model, last: list[StepReport], push: np.ndarray) -> Claim:
    """Claim 3: max slip at the front corner, cases 1 and 2 alike, case 3 furthest in y."""
    lx, ly, _ = model.mesh.size
    front_corner = np.array([np.sign(push[0]) * lx / 2, np.sign(push[1]) * ly / 2])
    h = math.hypot(lx / model.mesh.divisions[0], ly / model.mesh.divisions[1])
    cases = []
    for rep in last:
        vmax, at = extreme(model, rep.slip, np.ones(rep.slip.shape, bool), np.argmax)
        cases.append({
            "max_slip": vmax, "max_slip_at": at,
            "distance_to_front_corner": float(np.hypot(*(np.asarray(at) - front_corner))),
            "lower_centroid_x": float(rep.lower_centroid[0]),
            "lower_centroid_y": float(rep.lower_centroid[1]),
        })
    c12 = abs(cases[0]["max_slip"] - cases[1]["max_slip"]) / cases[0]["max_slip"]
    y = [c["lower_centroid_y"] for c in cases]
    return Claim(
        "3_sliding_slip",
        "max slip at the front corner; case 1 and case 2 max slips close; larger y displacement for case 3",
        {"cases": cases, "case1_case2_relative_difference": c12},
        (
            Check("max slip distance to the front corner: measured "
                  + ", ".join(f"{c['distance_to_front_corner'] * 1e3:.2f} mm" for c in cases)
                  + f", criterion <= one element diagonal ({h * 1e3:.2f} mm)",
                  all(c["distance_to_front_corner"] <= h for c in cases)),
            Check(f"case 1 vs case 2 max slip difference: measured {c12:.2%}, criterion < {CLOSE_RTOL:.0%}",
                  c12 < CLOSE_RTOL),
            Check("lower-face y displacement: measured " + _joined([v * 1e3 for v in y], ".4f")
                  + " mm, criterion case 3 largest",
                  y[2] > max(y[0], y[1])),
        ),
    )


def claim_sliding_normal_reaction(model: Model, last: list[StepReport], push: np.ndarray) -> Claim:
    """Claim 4: ``r_n`` max in front, min behind, both alike across cases."""
    rn = field_extremes(model, last, "r_n", push)
    p = field_extremes(model, last, "pressure", push)
    return Claim(
        "4_sliding_normal_reaction",
        "r_n max in the front area, min in the back area; max and min very close for all cases",
        {"r_n": rn, "pressure": p, "tangential_force": [float(math.hypot(*rep.tangential_force)) for rep in last]},
        (
            Check("r_n extremes: criterion max ahead of the centre, min behind it (along the push)",
                  all(r["max_along_push"] > 0 > r["min_along_push"] for r in rn["cases"])),
            Check("pressure extremes: criterion max ahead of the centre, min behind it",
                  all(r["max_along_push"] > 0 > r["min_along_push"] for r in p["cases"])),
            Check(f"r_n max spread across cases: measured {rn['max_spread']:.1%}, criterion < {CLOSE_RTOL:.0%}",
                  rn["max_spread"] < CLOSE_RTOL),
            Check(f"r_n min spread across cases: measured {rn['min_spread_of_max']:.1%} of the mean max, "
                  f"criterion < {CLOSE_RTOL:.0%}", rn["min_spread_of_max"] < CLOSE_RTOL),
        ),
    )


def claim_twist(last: list[StepReport]) -> Claim:
    """Claim 5: no twist for isotropic friction, a twist growing with the anisotropy."""
    cases = []
    for rep in last:
        lo = rep.lower_centroid[:2]
        cases.append({
            "twist_deg": math.degrees(rep.twist),
            "lower_direction_deg": math.degrees(math.atan2(lo[1], lo[0])),
            "lag_direction_deg": math.degrees(math.atan2(rep.lag[1], rep.lag[0])),
            "lower_yaw_deg": math.degrees(rep.lower_yaw),
        })
    tw = [abs(c["twist_deg"]) for c in cases]
    return Claim(
        "5_twist",
        "isotropic: lower and upper faces move in the same direction, no twist; anisotropic: different "
        "directions, the block twists, more for case 3",
        {"cases": cases},
        (
            Check(f"case 1 |twist|: measured {tw[0]:.2g}°, criterion < {TWIST_ZERO_DEG}°", tw[0] < TWIST_ZERO_DEG),
            Check(f"case 2, 3 |twist|: measured {tw[1]:.3f}°, {tw[2]:.3f}°, criterion > {TWIST_ZERO_DEG}°",
                  min(tw[1:]) > TWIST_ZERO_DEG),
            Check(f"|twist| case 3 vs case 2: measured {tw[2]:.3f}° vs {tw[1]:.3f}°, criterion case 3 larger",
                  tw[2] > tw[1]),
        ),
    )


def measure_claims(runs: list[Run], push: np.ndarray) -> tuple[Claim, ...]:
    """The five claims of sect. 9.1 / 9.2 on the completed runs of the three cases
    (same mesh), ``push`` the (2,) push direction."""
    model = runs[0].model
    first = [r.reports[0] for r in runs]
    last = [r.reports[-1] for r in runs]
    return (
        claim_compression_slip(model, first),
        claim_compression_normal_reaction(model, first, push),
        claim_sliding_slip(model, last, push),
        claim_sliding_normal_reaction(model, last, push),
        claim_twist(last),
    )
