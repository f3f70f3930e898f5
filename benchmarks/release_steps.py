"""The rest pose after a frictional pad's release (load control, issue 39) against the number of
load steps: the trade-off between the release's cost (Newton iterations, against the pushes') and
its error (the rest against a ``--reference``-step release, in units of the loaded lag).

The block of benchmarks/release_refinement.py: rubber 40 x 30 x 20 mm (3 x 2 x 2 hex8, quadrature
2, E 2 MPa, nu 0.45, 1000 kg/m^3), floor 0.6 / 0.2 at 20 deg, pressed 0.4 mm, pushed twice (0.6,
0.2) mm and 1 deg, pad ``ratio`` x the floor's friction; midpoint load steps (the default scheme).
Each row: the steps, the release's Newton iterations and their ratio to the pushes', the load
steps the midpoint rule took in two solves (``two_halves``: its half step extrapolated by less than
all of it, ``w < 1``, then backward Euler: a contact leaves its branch within the step), the rest
status and its distance from the reference's rest / lag.

    python benchmarks/release_steps.py [--steps 4 6 8 12 16 32] [--reference 64] [--ratios 0.01 1 100]

Writes ``benchmarks/results/release_steps.json``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, Release, block_mesh, release_to_rest, run

FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))


def sweep(ratio: float, steps: list[int], reference: int) -> list[dict]:
    """The release of the block with a pad of ``ratio`` x the floor's friction in each of ``steps``."""
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=Friction(FLOOR[0] * ratio, FLOOR[1] * ratio, FLOOR[2]))
    state, pushes = run(m, [Command(dz=-4e-4), PUSH, PUSH])
    lag, push_it = float(np.linalg.norm(pushes[-1].lag)), sum(r.newton_iterations for r in pushes)
    rests, rows = {}, []
    for n in [reference, *steps]:
        _, release, rest = release_to_rest(m, state, Release("lift", n, max_steps=10 * n + 100), pushes[-1])
        rests[n] = release[-1].lower_centroid[:2]
        it = sum(r.newton_iterations for r in release)
        rows.append({"ratio": ratio, "steps": n, "lag": lag, "push_newton": push_it, "release_newton": it,
                     "cost_ratio": it / push_it, "status": rest.status,
                     "two_halves": sum("two backward-Euler" in r.message or "then backward Euler" in r.message
                                       for r in release),
                     "error_vs_reference": float(np.linalg.norm(rests[n] - rests[reference]) / lag)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, nargs="+", default=[4, 6, 8, 12, 16, 32])
    parser.add_argument("--reference", type=int, default=64)
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.01, 1.0, 100.0])
    args = parser.parse_args()
    rows = []
    print(f"{'ratio':>6} {'steps':>5} {'rel it':>6} {'/push':>6} {'halves':>6} {'status':>11} {'error/lag':>10}")
    for ratio in args.ratios:
        for row in sweep(ratio, args.steps, args.reference):
            rows.append(row)
            print(f"{ratio:6g} {row['steps']:5d} {row['release_newton']:6d} {row['cost_ratio']:6.2f} "
                  f"{row['two_halves']:6d} {row['status']:>11} {row['error_vs_reference']:10.2e}", flush=True)
    print("wrote", write_results("release_steps", {"reference": args.reference, "rows": rows}))


if __name__ == "__main__":
    main()
