"""Time of one push step on the planning mesh (8 x 8 x 3 hex8, 2x2x2 Gauss points),
the unit cost of a planner's FE rollout, with the same reference ratio as
``paper_case.py`` (step / one assembly + factorisation + solve).

    python benchmarks/planning_step.py [--elements 8 8 3] [--steps 8]

Prints a table and writes ``benchmarks/results/planning_step.json``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, initial_state, step
from paper_case import reference_cost


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", type=int, nargs=3, default=[8, 8, 3])
    parser.add_argument("--steps", type=int, default=8)
    args = parser.parse_args(argv)
    model = Model(block_mesh((0.02, 0.02, 0.01), tuple(args.elements)), Material(210e9, 0.3),
                  Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions())
    ref = reference_cost(model)
    state, rep = step(model, initial_state(model), Command(dz=-1e-4))
    a = math.radians(45.0)
    push = Command(dx=0.16e-3 * math.cos(a), dy=0.16e-3 * math.sin(a))
    walls = []
    for _ in range(args.steps):
        t0 = time.perf_counter()
        state, rep = step(model, state, push)
        walls.append(time.perf_counter() - t0)
        assert rep.converged, rep.message
    walls = np.array(walls)
    print(f"planning mesh {args.elements}, {model.mesh.n_dofs} dofs, {model.n_contacts} contacts")
    print(f"press step {rep.wall_time:.3f} s; push step median {np.median(walls) * 1e3:.1f} ms, "
          f"min {walls.min() * 1e3:.1f} ms, max {walls.max() * 1e3:.1f} ms; reference {ref * 1e3:.1f} ms; "
          f"median ratio {np.median(walls) / ref:.1f}")
    result = {"elements": args.elements, "n_dofs": model.mesh.n_dofs, "reference_s": ref,
              "push_step_s": walls.tolist(), "median_s": float(np.median(walls)),
              "median_ratio_to_reference": float(np.median(walls) / ref)}
    print(f"wrote {write_results('planning_step', result)}")
    return result


if __name__ == "__main__":
    main()
