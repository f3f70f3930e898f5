"""From which order of the local Newton matrix Krylov steps beat a new LU (issue 32).

The local Newton method (``fe_contact.contact.local_solver``) either factorises its
Newton matrix at every step or, from order ``_KRYLOV_MIN_ORDER``, solves later steps
with GMRES preconditioned by the kept LU factors.  This times the local phase (and the
whole steps, CPU) of a press and three pushes on blocks of 6 x 6 x 2 ... 16 x 16 x 4
hex8 (quadrature 2; the order is 3 x the lower-face nodes), once with the threshold
above every order (an LU each step) and once below (Krylov steps), alternating, one
BLAS thread.  Writes ``benchmarks/results/krylov_order.json``.

    FE_CONTACT_DENSE_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/krylov_order.py
"""

from __future__ import annotations

import time

import numpy as np

import fe_contact.contact.local_solver as local_solver
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, initial_state, step, warm_up

from _common import write_results

MESHES = ((6, 2), (8, 3), (10, 3), (12, 4), (14, 4), (16, 4))
COMMANDS = (Command(dz=-1e-4), Command(dx=1e-4, dy=1e-4), Command(dx=1.2e-4, dy=0.8e-4), Command(dx=1e-4, dy=1e-4))
PATHS = {"lu": 10**9, "krylov": 1}  # thresholds that force each path


def run(model: Model, threshold: int) -> dict:
    local_solver._KRYLOV_MIN_ORDER = threshold
    state, local, iterations = initial_state(model), 0.0, 0
    c0 = time.process_time()
    for command in COMMANDS:
        state, report = step(model, state, command)
        assert report.converged, report.message
        local += report.timings["local"]
        iterations += report.contact_iterations
    return {"local_s": local, "steps_cpu_s": time.process_time() - c0, "local_iterations": iterations,
            "lower_centroid": report.lower_centroid.tolist()}


def main() -> None:
    default = local_solver._KRYLOV_MIN_ORDER
    warm_up()
    rows = []
    for n, nz in MESHES:
        model = Model(block_mesh((0.02, 0.02, 0.01), (n, n, nz)), Material(210e9, 0.3), Friction(0.3, 0.05, 0.0),
                      quadrature=2, options=SolverOptions())
        runs = {path: [] for path in PATHS}
        for _ in range(2):
            for path, threshold in PATHS.items():
                runs[path].append(run(model, threshold))
        med = {path: {k: float(np.median([r[k] for r in rs])) for k in ("local_s", "steps_cpu_s", "local_iterations")}
               for path, rs in runs.items()}
        gap = float(np.max(np.abs(np.subtract(runs["lu"][0]["lower_centroid"], runs["krylov"][0]["lower_centroid"]))))
        rows.append({"elements": [n, n, nz], "order": 3 * model.n_contacts, **med, "lower_centroid_gap_m": gap})
        print(f"order {3 * model.n_contacts:5d}: local LU {med['lu']['local_s'] * 1e3:7.1f} ms "
              f"Krylov {med['krylov']['local_s'] * 1e3:7.1f} ms (ratio {med['krylov']['local_s'] / med['lu']['local_s']:.2f}); "
              f"steps CPU {med['lu']['steps_cpu_s'] * 1e3:.0f} / {med['krylov']['steps_cpu_s'] * 1e3:.0f} ms; "
              f"lower centroid gap {gap:.1e} m")
    local_solver._KRYLOV_MIN_ORDER = default
    print(f"wrote {write_results('krylov_order', {'threshold': default, 'rows': rows})}")


if __name__ == "__main__":
    main()
