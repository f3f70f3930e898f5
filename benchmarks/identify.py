"""Identification of anisotropic friction from observed pushes and the closed loop
(issue 20), measured as a user runs them: every ``pushplan`` call is a process,
timed from start to exit.

    python benchmarks/identify.py
    python benchmarks/identify.py --coverage 20     # do the 95 % intervals cover the truth? (4 cases x 20 draws)

The truth is the steel block of the planning scenarios (20 x 20 x 10 mm, pressed
0.1 mm) on mu_x = 0.32, mu_y = 0.18 with t_x at 25 deg; observations come from
``pushplan simulate --observations`` with Gaussian noise of 1 um on the pose and 1 %
on each force component; ``pushplan identify`` starts from an isotropic guess
(0.25, 0.25, 0 deg).  Prints the table of docs/identification.md, writes
``benchmarks/results/identify.json`` and ``docs/figures/identified_friction_ellipse.png``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import write_results
from pushplan.config.observations import Observations, observations_to_csv, read_observations
from pushplan.identify.figure import ellipse_figure

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"mu_x": 0.32, "mu_y": 0.18, "angle_deg": 25.0}
GUESS = {"mu_x": 0.25, "mu_y": 0.25, "angle_deg": 0.0}
ELEMENTS = [8, 8, 2]
SCENARIO = """name = "{name}"
[block]
size = [0.020, 0.020, 0.010]
elements = {elements}
quadrature = 2
[material]
young = 210.0e9
poisson = 0.3
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = {angle_deg}
[[load]]
dz = -0.1e-3
{pushes}
[solver]
local_method = "newton"
{plan}"""
PLAN = """[plan]
x = 0.6e-3
y = 0.3e-3
steps = 4
max_step = 0.25e-3
tolerance = 0.3e-6
planning_elements = [4, 4, 2]
planning_quadrature = 2
"""


def pushes(directions) -> str:
    return "".join(f"[[load]]\ndistance = 1e-4\ndirection_deg = {d}\n" for d in directions)


def pushplan(*args) -> float:
    """Run ``pushplan ARGS`` as a process; wall time from start to exit, s."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pushplan.cli", *args, "--quiet"], check=True, cwd=ROOT,
                   stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return time.perf_counter() - t0


def noisy(obs: Observations, seed: int) -> Observations:
    rng = np.random.default_rng(seed)
    values = {k: v + rng.normal(0.0, 1e-6, v.shape) if k in ("lower_x", "lower_y") else v + rng.normal(0.0, 0.01 * abs(v))
              for k, v in obs.values.items() if k != "lower_yaw_deg"}
    return Observations(obs.commands, values)


def case(work: Path, name: str, directions, seed: int, suggest: int | None = None) -> dict:
    d = work / name
    d.mkdir()
    (d / "truth.toml").write_text(SCENARIO.format(name="truth", elements=ELEMENTS, pushes=pushes(directions),
                                                  plan="", **TRUTH))
    (d / "guess.toml").write_text(SCENARIO.format(name="guess", elements=ELEMENTS, pushes="", plan="", **GUESS))
    t_sim = pushplan("simulate", str(d / "truth.toml"), "--out", str(d / "sim"), "--no-recording",
                     "--observations", str(d / "clean.csv"))
    (d / "observed.csv").write_text(observations_to_csv(noisy(read_observations(d / "clean.csv"), seed)))
    extra = ["--suggest", str(suggest)] if suggest else []
    t_id = pushplan("identify", str(d / "guess.toml"), "--observations", str(d / "observed.csv"), "--out",
                    str(d / "id"), "--pose-noise", "1e-6", "--force-noise", "1", "--force-noise-rel", "0.01", *extra)
    doc = json.loads((d / "id" / "identified.json").read_text())
    return {"name": name, "directions_deg": list(directions), "simulate_s": t_sim, "identify_s": t_id, "doc": doc}


def closed_loop(work: Path, identify: bool) -> dict:
    d = work / f"closed_loop_{identify}"
    d.mkdir()
    (d / "model.toml").write_text(SCENARIO.format(name="model", elements=[4, 4, 2], pushes="", plan=PLAN,
                                                  mu_x=0.3, mu_y=0.15, angle_deg=25.0))
    (d / "truth.toml").write_text(SCENARIO.format(name="truth", elements=[4, 4, 2], pushes="", plan="",
                                                  mu_x=0.39, mu_y=0.195, angle_deg=25.0))
    t = pushplan("closed-loop", str(d / "model.toml"), "--truth", str(d / "truth.toml"), "--out", str(d / "out"),
                 "--no-recording", *(["--identify"] if identify else []))
    doc = json.loads((d / "out" / "closed_loop.json").read_text())
    return {"identify": identify, "wall_s": t, "closed_error": doc["closed_loop"]["final_error"],
            "open_error": doc["open_loop"]["final_error"], "final_estimates": doc["final_estimates"]}


def row(c: dict) -> str:
    p = c["doc"]["parameters"]
    cells = []
    for k in ("mu_x", "mu_y", "angle_deg"):
        s = p[k]["sigma"]
        cells.append(f"{p[k]['estimate']:.4f} ± {s:.2g}" + ("" if p[k]["identifiable"] else " (n.i.)")
                     if s is not None else f"{p[k]['estimate']:.4f} ± inf (n.i.)")
    dirs = ", ".join(f"{d:g}" for d in c["directions_deg"])
    return (f"| {c['name']} | {dirs} | " + " | ".join(cells)
            + f" | {c['doc']['solver']['fe_rollouts']} | {c['identify_s']:.1f} |")


COVERAGE_CASES = {
    # name: (truth mesh, material (E, nu), press dz, push length, directions); the model mesh is [4, 4, 2]
    "a_same_mesh": ([4, 4, 2], (210.0e9, 0.3), -1e-4, 1e-4, (10, 10, 100, 100, 200)),
    "b_truth_twice_as_fine": ([8, 8, 4], (210.0e9, 0.3), -1e-4, 1e-4, (10, 10, 100, 100, 200)),
    "c_partial_slip": ([4, 4, 2], (5.0e6, 0.45), -3e-4, 1e-4, (10, 10, 100, 100, 200)),
    "d_steel_sliding": ([6, 6, 3], (210.0e9, 0.3), -1e-4, 5e-4, (10, 100, 200, 300)),
}


def coverage_case(name: str, draws: int) -> dict:
    """Identify one case's truth under ``draws`` noise draws (in-process) and count how
    often the reported 95 % interval contains the true value."""
    import dataclasses
    import math
    import tomllib

    from fe_contact import Command
    from pushplan.config import parse_scenario
    from pushplan.identify import NoiseModel, identify
    from pushplan.run import drive
    from pushplan.run.observations import observations_from_steps

    elements, (young, poisson), dz, length, directions = COVERAGE_CASES[name]
    text = SCENARIO.format(name="truth", elements=elements, pushes="", plan="", **TRUTH)
    text = text.replace("young = 210.0e9", f"young = {young}").replace("poisson = 0.3", f"poisson = {poisson}")
    truth = parse_scenario(tomllib.loads(text.replace("dz = -0.1e-3", f"dz = {dz}")))
    cmds = [Command(0.0, 0.0, dz, 0.0)] + [Command(length * math.cos(math.radians(d)),
                                                   length * math.sin(math.radians(d)), 0.0, 0.0) for d in directions]
    clean = observations_from_steps(drive(truth.model(), cmds).summary.steps)
    guess = dataclasses.replace(truth, elements=(4, 4, 2), **GUESS)
    rows = []
    for seed in range(draws):
        res = identify(guess, noisy(clean, 100 + seed), NoiseModel(1e-6, 1.0, 0.01))
        row = {"seed": seed, "converged": res.converged, "fe_rollouts": res.fe_rollouts, "wall_time_s": res.wall_time,
               "reduced_chi2": res.chi2 / (res.n_values - len(res.names)), "chi2_factor": res.uncertainty.chi2_factor}
        for j, k in enumerate(res.names):
            lo, hi = res.interval[j]
            row[k] = {"estimate": float(res.estimate[j]), "sigma": float(res.sigma[j]),
                      "sigma_linearised": float(res.sigma_linear[j]), "covered": bool(lo <= TRUTH[k] <= hi),
                      "method": res.uncertainty.method[j], "identifiable": res.identifiable[j]}
        rows.append(row)
    covered = {k: int(sum(r[k]["covered"] for r in rows)) for k in TRUTH}
    return {"case": name, "truth_mesh": elements, "model_mesh": [4, 4, 2], "young": young, "push": length,
            "directions_deg": list(directions), "draws": draws, "covered_95": covered,
            "converged": int(sum(r["converged"] for r in rows)), "runs": rows}


def coverage(draws: int) -> dict:
    """The issue-29 coverage study: for each case of :data:`COVERAGE_CASES`, how many of
    ``draws`` reported 95 % intervals contain the truth (acceptance: >= 17 of 20)."""
    results = []
    for name in COVERAGE_CASES:
        c = coverage_case(name, draws)
        results.append(c)
        est = {k: [r[k]["estimate"] for r in c["runs"]] for k in TRUTH}
        sig = {k: [r[k]["sigma"] for r in c["runs"]] for k in TRUTH}
        print(f"{name}: 95 % intervals containing the truth: "
              + ", ".join(f"{k} {c['covered_95'][k]}/{draws}" for k in TRUTH)
              + f"; converged {c['converged']}/{draws}; "
              + ", ".join(f"{k} {np.mean(est[k]):.4f} (sigma {np.median(sig[k]):.2g})" for k in TRUTH), flush=True)
    payload = {"draws": draws, "truth": TRUTH, "guess": GUESS, "cases": results}
    print(f"wrote {write_results('identify_coverage', payload)}")
    return payload


def main() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        cases = [case(work, "three directions", [10, 10, 100, 100, 200], 1),
                 case(work, "along t_x", [25, 25, 25, 25], 2),
                 case(work, "along world x", [0, 0, 0, 0], 3, suggest=4)]
        suggested = cases[-1]["doc"]["suggested"]["directions_deg"]
        cases.append(case(work, "suggested (from world x)", suggested, 4))
        loops = [closed_loop(work, False), closed_loop(work, True)]
    print(f"truth: mu_x = {TRUTH['mu_x']}, mu_y = {TRUTH['mu_y']}, angle = {TRUTH['angle_deg']} deg; "
          f"mesh {ELEMENTS}, noise 1 um / 1 %")
    print("| pushes | directions (deg) | mu_x | mu_y | angle (deg) | FE rollouts | identify (s) |")
    print("|---|---|---|---|---|---|---|")
    for c in cases:
        print(row(c))
    for lp in loops:
        print(f"closed loop{' --identify' if lp['identify'] else ''}: {lp['closed_error']['position'] * 1e6:.3f} um, "
              f"open loop {lp['open_error']['position'] * 1e6:.3f} um ({lp['wall_s']:.1f} s)")
    figure = ROOT / "docs" / "figures" / "identified_friction_ellipse.png"
    ellipse_figure([(f"{c['name']}: {', '.join(f'{d:g}' for d in c['directions_deg'])} deg", c["doc"])
                    for c in cases if c["name"] != "along world x"], TRUTH, figure)
    payload = {"truth": TRUTH, "guess": GUESS, "elements": ELEMENTS, "cases": cases, "closed_loop": loops}
    print(f"wrote {write_results('identify', payload)} and {figure}")
    return payload


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coverage", type=int, metavar="N", help="only the coverage study, N noise draws")
    args = parser.parse_args()
    coverage(args.coverage) if args.coverage else main()
