"""Time of one push step on the planning mesh (8 x 8 x 3 hex8, 2x2x2 Gauss points),
the unit cost of a planner's FE rollout, with the same reference ratio as
``paper_case.py`` (step / one assembly + factorisation + solve).

Two sequences from the pressed block, each step chained on the last:

* ``steady``: the same 0.16 mm push at 45 deg repeated.  Once the block slides
  steadily, the rigid predictor (the block carried by the command) is nearly
  the solution, and a step takes one or two Newton iterations.
* ``varied``: 0.16 mm pushes in seeded random directions with random turns of
  up to 0.5 deg, as in a planner's rollouts: every step changes the slip
  direction, the harder and more representative case.

    python benchmarks/planning_step.py [--elements 8 8 3] [--steps 12]

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

PUSH = 0.16e-3  # m per step


def sequences(steps: int) -> dict[str, list[Command]]:
    a = math.radians(45.0)
    rng = np.random.default_rng(0)
    varied = []
    for _ in range(steps):
        direction = rng.uniform(0.0, 2.0 * math.pi)
        varied.append(Command(dx=PUSH * math.cos(direction), dy=PUSH * math.sin(direction),
                              dtheta=math.radians(rng.uniform(-0.5, 0.5))))
    return {"steady": [Command(dx=PUSH * math.cos(a), dy=PUSH * math.sin(a))] * steps, "varied": varied}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", type=int, nargs=3, default=[8, 8, 3])
    parser.add_argument("--steps", type=int, default=12)
    args = parser.parse_args(argv)
    model = Model(block_mesh((0.02, 0.02, 0.01), tuple(args.elements)), Material(210e9, 0.3),
                  Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions())
    ref = reference_cost(model)
    pressed, rep = step(model, initial_state(model), Command(dz=-1e-4))
    print(f"planning mesh {args.elements}, {model.mesh.n_dofs} dofs, {model.n_contacts} contacts; "
          f"press step {rep.wall_time:.3f} s; reference {ref * 1e3:.1f} ms")
    result = {"elements": args.elements, "n_dofs": model.mesh.n_dofs, "reference_s": ref}
    for name, commands in sequences(args.steps).items():
        state, walls, iterations = pressed, [], []
        for cmd in commands:
            t0 = time.perf_counter()
            state, rep = step(model, state, cmd)
            walls.append(time.perf_counter() - t0)
            assert rep.converged, rep.message
            iterations.append(rep.newton_iterations)
        walls = np.array(walls)
        print(f"{name:>6}: push step median {np.median(walls) * 1e3:.1f} ms, min {walls.min() * 1e3:.1f} ms, "
              f"max {walls.max() * 1e3:.1f} ms; median ratio {np.median(walls) / ref:.1f}; "
              f"Newton iterations {iterations}")
        result[name] = {"push_step_s": walls.tolist(), "newton_iterations": iterations,
                        "median_s": float(np.median(walls)), "median_ratio_to_reference": float(np.median(walls) / ref)}
    print(f"wrote {write_results('planning_step', result)}")
    return result


if __name__ == "__main__":
    main()
