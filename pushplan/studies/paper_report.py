"""The paper reproduction's report: :class:`PaperReport` (what ``run_paper`` found,
typed) turned into ``report.json`` by :meth:`PaperReport.to_dict`, and
``report.md``, the human-readable version of that file."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..config.scenario import Scenario
from ..run import Run
from .paper_cases import StepRecord
from .paper_claims import Claim
from .paper_figures import MAGNIFICATION

REPORT_FILES = ("report.json", "report.md")


@dataclass(frozen=True)
class PaperCase:
    """One friction case: its scenario, its run and the records of its converged steps."""

    scenario: Scenario
    run: Run
    steps: tuple[StepRecord, ...]

    @property
    def name(self) -> str:
        return self.scenario.name

    def to_dict(self) -> dict:
        summary = self.run.summary
        return {
            "name": self.name, "scenario": summary.scenario, "status": summary.status.value,
            "failure": None if summary.failure is None else summary.failure.to_dict(),
            "elapsed_s": summary.elapsed_s, "steps": [s.to_dict() for s in self.steps],
        }


@dataclass(frozen=True)
class PaperReport:
    """What ``pushplan paper`` found: the cases, the claims (None unless every case
    completed), the files written (relative to the output folder) and the wall times, s."""

    cases: tuple[PaperCase, ...]
    claims: tuple[Claim, ...] | None
    files: tuple[str, ...]
    push_direction_deg: float
    simulate_s: float
    figures_s: float
    wall_time_s: float

    @property
    def completed(self) -> bool:
        return all(c.run.completed for c in self.cases)

    @property
    def failed_cases(self) -> list[str]:
        return [c.name for c in self.cases if not c.run.completed]

    def to_dict(self) -> dict:
        """The content of ``report.json``."""
        sc = self.cases[0].scenario
        return {
            "status": "completed" if self.completed else "failed",
            "run": {
                "elements": list(sc.elements), "quadrature": sc.quadrature, "local_method": sc.solver.local_method,
                "simulate_s": self.simulate_s, "figures_s": self.figures_s, "wall_time_s": self.wall_time_s,
                "magnification": MAGNIFICATION, "push_direction_deg": self.push_direction_deg,
            },
            "cases": [c.to_dict() for c in self.cases],
            "claims": None if self.claims is None else {c.key: c.to_dict() for c in self.claims},
            "files": [*self.files, *REPORT_FILES],
        }


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
            "| lower centroid mm | dir ° | lower dev. ° | yaw ° | N kN | T kN | dissip. J | newton/local | s |",
            "|---" * 16 + "|",
        ]
        if case["failure"]:
            lines[-2:-2] = [f"Failed at step {case['failure']['step']} ({case['failure']['status']}): "
                            f"{case['failure']['message']}", ""]
        for s in case["steps"]:
            lo = s["lower_centroid"]
            d = "-" if s["lower_direction_deg"] is None else f"{s['lower_direction_deg']:.2f}"
            dev = s["lower_direction_deviation_deg"]
            dev = "-" if dev is None else f"{dev:.3f}"
            lines.append(
                f"| {s['step']} | {s['max_slip'] * 1e6:.2f} {_mm(s['max_slip_at'])} "
                f"| {s['r_n_max']:.0f} {_mm(s['r_n_max_at'])} | {s['r_n_min']:.0f} {_mm(s['r_n_min_at'])} "
                f"| {s['pressure_max'] / 1e6:.0f} {_mm(s['pressure_max_at'])} "
                f"| {s['pressure_min'] / 1e6:.0f} {_mm(s['pressure_min_at'])} "
                f"| {s['n_stick']}/{s['n_slip']}/{s['n_separated']} | ({lo[0] * 1e3:.4f}, {lo[1] * 1e3:.4f}) | {d} "
                f"| {dev} | {s['lower_yaw_deg']:.4f} | {s['normal_force'] / 1e3:.1f} "
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
