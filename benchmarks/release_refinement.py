"""The rest pose after a frictional pad's release (load control, issue 39) against the
release's numerical settings: 4 x the load steps, the tolerances / 10 (``newton_tol``,
``local_tol`` and the release's ``path_tol`` with them), the pad's regularisation / 10,
and the release's path solved to ``newton_tol`` (``path_at_newton_tol``: the path
tolerance's effect), for pad / floor friction ratios 0.01, 1 and 100, and the 100 x pad
against the bonded lift; in units of the loaded lag.

The block of tests/test_pad.py: rubber 40 x 30 x 20 mm (3 x 2 x 2 hex8, quadrature 2,
E 2 MPa, nu 0.45, 1000 kg/m^3), floor 0.6 / 0.2 at 20 deg, pressed 0.4 mm, pushed twice
(0.6, 0.2) mm and 1 deg.

    python benchmarks/release_refinement.py [--steps 6 24] [--name release_refinement]

Writes ``benchmarks/results/release_refinement.json`` (``NAME.json``).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, Release, SolverOptions, block_mesh, release_to_rest, run

FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))


PATH_PER_TOL = SolverOptions().path_tol / SolverOptions().newton_tol
"""The release's path tolerance moves with the tolerances (the defaults at ``tol`` 1e-10)."""


def rest(ratio, steps: int, tol: float = 1e-10, beta: float = 1e-2, path: float | None = None) -> dict:
    """Rest of the block with a pad of ``ratio`` x the floor's friction (None: bonded); ``path`` the
    release's path tolerance (default: ``PATH_PER_TOL tol``)."""
    pad = None if ratio is None else Friction(FLOOR[0] * ratio, FLOOR[1] * ratio, FLOOR[2])
    path = PATH_PER_TOL * tol if path is None else path
    options = SolverOptions(newton_tol=tol, local_tol=tol, path_tol=path, pad_regularisation=beta)
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=pad, options=options)
    t0 = time.process_time()
    state, pushes = run(m, [Command(dz=-4e-4), PUSH, PUSH])
    _, release, status = release_to_rest(m, state, Release("lift", steps, max_steps=10 * steps + 100), pushes[-1])
    return {"rest": release[-1].lower_centroid[:2], "lag": float(np.linalg.norm(pushes[-1].lag)),
            "status": status.status, "newton": sum(r.newton_iterations for r in release),
            "seconds": time.process_time() - t0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, nargs=2, default=[6, 24], help="the base steps (a frictional pad's default) and x4")
    parser.add_argument("--name", default="release_refinement", help="results file name (benchmarks/results/NAME.json)")
    args = parser.parse_args()
    base, fine = args.steps
    rows = []
    bonded = rest(None, base)
    for ratio in (0.01, 1.0, 100.0):
        ref = rest(ratio, base)
        lag = ref["lag"]
        row = {"ratio": ratio, "steps": base, "lag": lag, "status": ref["status"], "newton": ref["newton"]}
        for name, kw in (("steps_x4", {"steps": fine}), ("tolerances_div10", {"steps": base, "tol": 1e-11}),
                         ("regularisation_div10", {"steps": base, "beta": 1e-3}),
                         ("path_at_newton_tol", {"steps": base, "path": 1e-10})):
            other = rest(ratio, **kw)
            row[name] = float(np.linalg.norm(other["rest"] - ref["rest"]) / lag)
            row[name + "_status"] = other["status"]
        if ratio == 100.0:
            row["vs_bonded"] = float(np.linalg.norm(ref["rest"] - bonded["rest"]) / bonded["lag"])
            row["vs_bonded_fine"] = float(np.linalg.norm(rest(ratio, fine)["rest"] - bonded["rest"]) / bonded["lag"])
        rows.append(row)
        print({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    print("wrote", write_results(args.name, {"steps": [base, fine], "rows": rows}))


if __name__ == "__main__":
    main()
