"""The cost of a frictional pad's release (load control, issue 39) against the pushes
that loaded the block, for pad / floor friction ratios 0.01 ... 100, in Newton
iterations and process time, on one run.

The block of issue 39: rubber 28 x 22 x 14 mm (6 x 5 x 3 hex8, quadrature 2, E 2 MPa,
nu 0.45, 1000 kg/m^3), floor 0.65 / 0.3 at 20 deg, pressed 0.25 mm and pushed 3 x 0.8 mm
along x by a pad of ``ratio`` times the floor's friction (same axes), then released in
``--steps`` load steps of the pad's load.  Also the issue's slippery pad (isotropic
0.0065).  Each row: the pushes' and the release's Newton iterations and their ratio,
the rest status, ``N / W - 1``, the rest pose's lower-face centroid, the loaded lag and the
process time of each phase (one core; the machine shared, so times are indicative).

    python benchmarks/release_cost.py [--steps 4 16] [--ratios 0.01 0.1 1 10 100] [--path-tol 1e-4]

``--path-tol``: the release's path tolerance (``SolverOptions.path_tol``, default its default).

Writes ``benchmarks/results/release_cost.json``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, Release, SolverOptions, block_mesh, release_to_rest, run

FLOOR = (0.65, 0.3, math.radians(20.0))
RATIOS = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
LOADS = [Command(dz=-2.5e-4)] + [Command(dx=8e-4)] * 3


def case(pad: Friction, steps: int, options: SolverOptions | None = None) -> dict:
    """Push and release of the issue's block with ``pad``, in ``steps`` load steps."""
    m = Model(block_mesh((0.028, 0.022, 0.014), (6, 5, 3)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=pad, options=options or SolverOptions())
    t0 = time.process_time()
    state, pushes = run(m, LOADS)
    t1 = time.process_time()
    _, release, rest = release_to_rest(m, state, Release("lift", steps), pushes[-1])
    t2 = time.process_time()
    push_it = sum(r.newton_iterations for r in pushes)
    release_it = sum(r.newton_iterations for r in release)
    return {"pad": [pad.mu_x, pad.mu_y], "steps": steps, "push_newton": push_it, "release_newton": release_it,
            "ratio": release_it / push_it, "release_steps": len(release), "status": rest.status,
            "normal_over_weight_minus_1": release[-1].normal_force / m.weight - 1.0,
            "rest_lower": release[-1].lower_centroid[:2].tolist(), "loaded_lower": pushes[-1].lower_centroid[:2].tolist(),
            "lag": float(np.linalg.norm(pushes[-1].lag)), "push_s": t1 - t0, "release_s": t2 - t1,
            "pushes_converged": all(r.converged for r in pushes)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, nargs="+", default=[4, 16])
    parser.add_argument("--ratios", type=float, nargs="+", default=RATIOS)
    parser.add_argument("--name", default="release_cost", help="results file name (benchmarks/results/NAME.json)")
    parser.add_argument("--path-tol", type=float, default=SolverOptions().path_tol,
                        help="the release's path tolerance (SolverOptions.path_tol)")
    args = parser.parse_args()
    options = SolverOptions(path_tol=args.path_tol)
    rows = []
    print(f"{'pad mu_x':>9} {'steps':>5} {'push it':>7} {'rel it':>6} {'ratio':>6} {'status':>11} {'N/W-1':>9} "
          f"{'push s':>6} {'rel s':>6}")
    pads = [Friction(0.0065, 0.0065)] + [Friction(FLOOR[0] * r, FLOOR[1] * r, FLOOR[2]) for r in args.ratios]
    for steps in args.steps:
        for pad in pads:
            row = case(pad, steps, options)
            rows.append(row)
            print(f"{pad.mu_x:9.4g} {steps:5d} {row['push_newton']:7d} {row['release_newton']:6d} {row['ratio']:6.2f} "
                  f"{row['status']:>11} {row['normal_over_weight_minus_1']:9.1e} {row['push_s']:6.1f} "
                  f"{row['release_s']:6.1f}", flush=True)
            worst = {s: max(r["ratio"] for r in rows if r["steps"] == s) for s in args.steps if
                     any(r["steps"] == s for r in rows)}
            path = write_results(args.name, {"floor": FLOOR[:2], "floor_angle_deg": 20.0, "path_tol": args.path_tol,
                                             "rows": rows,
                                             "worst_ratio": {str(k): v for k, v in worst.items()}})
    print("worst release / push Newton iterations:", worst)
    print("wrote", path)


if __name__ == "__main__":
    main()
