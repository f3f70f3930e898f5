"""Robust plans on rotated friction axes (issue 42, hidden cases): is the probability the
refinement reaches a limit of the physics or of the method?  The shipped
``scenarios/plan_robust.toml`` with its axes at 30 degrees, mu_x = 0.4 +- 0.015 (along the
target's x' component, badly known) and mu_y = 0.15 +- 0.003 (well known, at 120 degrees,
75 degrees from the target's direction), angle +- 0.3 degrees.

1. ``relaxation``: the final pose's spread over the sigma points after 3 pushes along the
   badly known axis and then ``n`` along the well-known one (FE, verification mesh): how
   far the block must slide before the lag built along x' stops spreading the pose.
2. ``plans``: the robust plan's predicted probability (level 0.9, 12 evaluations) with 5 and
   10 steps, the second start's slide capped at 2 commands (the earlier method) and
   uncapped (as many as the bounds allow).

    python benchmarks/robust_rotated.py

Writes ``benchmarks/results/robust_rotated.json``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from _common import write_results
from pushplan.config import load_scenario
from pushplan.config.plan import parse_plan
from pushplan.planning import plan, robust
from pushplan.planning.distribution import Distribution

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("mu_x", "mu_y", "angle_deg")
DISTRIBUTION = Distribution(NAMES, np.array([0.4, 0.15, 30.0]), np.diag([0.015, 0.003, 0.3]) ** 2)


def setting(steps: int):
    sc = load_scenario(ROOT / "scenarios" / "plan_robust.toml")
    sc = DISTRIBUTION.scenario(sc, DISTRIBUTION.mean)
    spec = parse_plan(sc)
    return sc, dataclasses.replace(spec, steps=steps, robust=dataclasses.replace(spec.robust, max_iterations=12,
                                                                                   monte_carlo=0))


def relaxation() -> list[dict]:
    sc, spec = setting(5)
    sigma = robust.SigmaRollouts(sc, DISTRIBUTION, spec)

    def along(phi):
        return spec.max_step * np.array([math.cos(math.radians(phi)), math.sin(math.radians(phi)), 0.0])

    rows = []
    for n in (0, 1, 3, 6, 10):
        u = np.vstack([np.tile(along(30.0), (3, 1)), np.tile(along(120.0), (n, 1))])
        ev = sigma.evaluate(u)
        sd = np.sqrt(np.diag(ev.covariance)[:2])
        rows.append({"pushes_along_30_deg": 3, "slides_along_120_deg": n, "sd_final_m": [float(v) for v in sd]})
        print(f"3 pushes along the badly known axis, then {n:2d} along the well-known one: final pose sd "
              f"{sd[0] * 1e6:.2f} / {sd[1] * 1e6:.2f} um", flush=True)
    return rows


def plans() -> list[dict]:
    rows = []
    for steps in (5, 10):
        sc, spec = setting(steps)
        nominal = plan(sc, spec, baseline=False)
        for cap in (2, None):
            robust.SLIDE_STEPS = cap
            t0 = time.perf_counter()
            r = robust.plan_robust(sc, DISTRIBUTION, spec, nominal)
            ev = r.evaluations[r.best]
            rows.append({"steps": steps, "slide_cap": cap, "reached": r.reached, "predicted": ev.probability,
                         "nominal_predicted": r.evaluations[0].probability, "evaluations": len(r.evaluations),
                         "sigma_point_rollouts": r.rollouts["sigma_point_rollouts"],
                         "wall_s": time.perf_counter() - t0})
            print(f"{steps} steps, slide cap {cap}: predicted {ev.probability:.3f} (nominal "
                  f"{r.evaluations[0].probability:.3f}) after {len(r.evaluations)} evaluations", flush=True)
    robust.SLIDE_STEPS = None
    return rows


def main() -> None:
    out = {"distribution": DISTRIBUTION.to_dict(), "relaxation": relaxation(), "plans": plans()}
    print(write_results("robust_rotated", out))


if __name__ == "__main__":
    main()
