"""Success probability against the tolerance, nominal and robust plans (issue 42), on the
shipped ``scenarios/plan_robust.toml`` with ``plan_robust_identified.json``: for each
tolerance the nominal plan for the estimate, the robust plan (level 0.9) and the Monte
Carlo check of both over the same 50 truths; the predicted probabilities, the Monte
Carlo fractions with their Clopper-Pearson 95 % intervals and the FE rollouts each costs.

    python benchmarks/robust_plan.py [--tolerances 2e-6 3e-6 ...] [--truths 50]

Writes ``benchmarks/results/robust_plan.json`` and ``docs/figures/robust_plan.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from _common import write_results
from pushplan.config import load_scenario
from pushplan.config.plan import parse_plan
from pushplan.identify.document import read_identified
from pushplan.planning import plan
from pushplan.planning.robust import plan_robust, robust_document

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "plan_robust.toml"
IDENTIFIED = ROOT / "scenarios" / "plan_robust_identified.json"
TOLERANCES = (2e-6, 3e-6, 4e-6, 6e-6)


def one(tolerance: float, truths: int) -> dict:
    """Both plans and their check at one tolerance (m)."""
    import dataclasses

    distribution = read_identified(IDENTIFIED)
    scenario = load_scenario(SCENARIO)
    scenario = distribution.scenario(scenario, distribution.mean)
    spec = parse_plan(scenario)
    spec = dataclasses.replace(spec, tolerance=tolerance, robust=dataclasses.replace(spec.robust, monte_carlo=truths))
    t0 = time.perf_counter()
    nominal = plan(scenario, spec, baseline=False)
    t1 = time.perf_counter()
    robust = plan_robust(scenario, distribution, spec, nominal)
    doc = robust_document(robust, spec)
    mc = doc["monte_carlo"]
    return {"tolerance": tolerance, "reached": doc["reached"],
            "robust": {"predicted": doc["predicted_probability"], "fraction": mc["robust"]["fraction"],
                       "interval_95": mc["robust"]["interval_95"]},
            "nominal": {"predicted": doc["nominal_predicted_probability"], "fraction": mc["nominal"]["fraction"],
                        "interval_95": mc["nominal"]["interval_95"], "status": nominal.status},
            "truths": mc["truths"], "evaluations": len(doc["evaluations"]),
            "nominal_fe_rollouts": nominal.rollouts, "robust_fe_rollouts": doc["fe_rollouts"],
            "wall_s": {"nominal": t1 - t0, **doc["wall_time_s"]}}


def figure(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tol = [1e6 * r["tolerance"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for name, color in (("nominal", "C3"), ("robust", "C0")):
        frac = [r[name]["fraction"] for r in rows]
        err = [[f - r[name]["interval_95"][0] for f, r in zip(frac, rows, strict=True)],
               [r[name]["interval_95"][1] - f for f, r in zip(frac, rows, strict=True)]]
        ax.errorbar(tol, frac, yerr=err, fmt="o-", color=color, capsize=3,
                    label=f"{name}: Monte Carlo ({rows[0]['truths']} truths, 95 % interval)")
        ax.plot(tol, [r[name]["predicted"] for r in rows], "x--", color=color, label=f"{name}: predicted")
    ax.axhline(0.9, color="0.6", ls=":", label="robust level 0.9")
    ax.set_xlabel("position tolerance (um)")
    ax.set_ylabel("probability within tolerance")
    ax.set_ylim(0, 1.05)
    ax.set_title("plan_robust: success over the identified friction distribution")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerances", type=float, nargs="+", default=list(TOLERANCES))
    ap.add_argument("--truths", type=int, default=50)
    args = ap.parse_args()
    rows = []
    for tol in args.tolerances:
        rows.append(one(tol, args.truths))
        r = rows[-1]
        print(f"tolerance {tol * 1e6:.3g} um: nominal predicted {r['nominal']['predicted']:.3f}, Monte Carlo "
              f"{r['nominal']['fraction']:.3f} {r['nominal']['interval_95']}; robust predicted "
              f"{r['robust']['predicted']:.3f}, Monte Carlo {r['robust']['fraction']:.3f} {r['robust']['interval_95']}"
              f"; sigma-point rollouts {r['robust_fe_rollouts']['sigma_point_rollouts']}, nominal "
              f"{r['nominal_fe_rollouts']}, wall {r['wall_s']}", flush=True)
    write_results("robust_plan", {"scenario": str(SCENARIO.relative_to(ROOT)), "rows": rows})
    figure(rows, ROOT / "docs" / "figures" / "robust_plan.png")


if __name__ == "__main__":
    main()
