"""Scaling of one compression step plus one push step with the number of dofs.

Blocks of the paper's proportions (2 : 2 : 1) with ``n x n x n/2`` hex8
(quadrature 2) at about 1e3, 1e4, 5e4 and 2e5 dofs.  Each size runs in its own
process so its peak memory (``ru_maxrss``) is its own; a size that exceeds
``--timeout`` seconds is reported as such.  Fits the exponent of time vs dofs
over the sizes that finished, and of the flops of one sparse factorisation: ours
(contact dofs last, with the inversion to ``W``) and plain nested dissection of the
same matrix: the cost of a sparse direct solve of the block alone, without contact.

    python benchmarks/scaling.py [--sizes 8 18 32 52] [--timeout 900]

Prints a table and writes ``benchmarks/results/scaling.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np

from _common import write_results

CHILD = r"""
import json, resource, sys, time
import numpy as np
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, initial_state, step
from fe_contact.contact.local_solver import solve_local
n = int(sys.argv[1])
model = Model(block_mesh((0.02, 0.02, 0.01), (n, n, max(1, n // 2))), Material(210e9, 0.3),
              Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions())
state = initial_state(model)
# load the compiled kernels first (cone projection, Alart-Curnier: the local
# Newton on one sliding contact calls both; the factorisation's extend-add: one
# step on a small block): a once-per-process cost (0.2-0.4 s) that would flatten
# the fit at the small sizes
solve_local(np.eye(3), np.array([[-1.0, 0.5, 0.5]]), 0.3, 0.05, method="newton")
small = Model(block_mesh((0.02, 0.02, 0.01), (4, 4, 2)), Material(210e9, 0.3), Friction(0.3, 0.05, 0.0),
              quadrature=2, options=SolverOptions())
step(small, initial_state(small), Command(dz=-1e-4))
t0 = time.perf_counter()
out = {"n": n, "dofs": model.mesh.n_dofs, "contacts": model.n_contacts, "steps": []}
for cmd in (Command(dz=-1e-4), Command(dx=2.26e-4, dy=2.26e-4)):
    state, rep = step(model, state, cmd, consume=True)
    out["steps"].append({"wall_s": rep.wall_time, "converged": rep.converged, **rep.timings})
out["wall_s"] = time.perf_counter() - t0
out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
# flops of one factorisation of K_ff: ours (contact dofs last, which leaves W), and
# plain nested dissection of the same matrix (no contact ordering, no W): the cost
# of a sparse direct solve of the block itself, contact or not (after the peak
# memory is read, the state's factors dropped first)
from fe_contact.linalg.cholesky import supernodal_structure
from fe_contact.fem.mesh import nested_dissection_parts
state = None
free = np.zeros(model.mesh.n_dofs, dtype=bool)
free[model.free_dofs] = True
parts = [d[free[d]] for d in ((3 * p[:, None] + np.arange(3)).ravel() for p in nested_dissection_parts(model.mesh))]
parts = [d for d in parts if d.size]
plain = supernodal_structure(model.pattern.indptr, model.pattern.indices, model.free_dofs, parts[:-1], parts[-1])
m = 3 * model.n_contacts
out["factor_flops"] = model.factor_structure.flops + 2 * m**3 / 3  # with the inversion to W
out["plain_factor_flops"] = plain.flops
print(json.dumps(out))
"""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[8, 18, 32, 52])
    parser.add_argument("--timeout", type=float, default=900.0)
    args = parser.parse_args(argv)
    rows = []
    for n in args.sizes:
        try:
            proc = subprocess.run([sys.executable, "-c", CHILD, str(n)], capture_output=True, text=True,
                                  timeout=args.timeout, check=True)
            row = json.loads(proc.stdout.strip().splitlines()[-1])
        except subprocess.TimeoutExpired:
            row = {"n": n, "timeout_s": args.timeout}
        except subprocess.CalledProcessError as exc:
            reason = "killed (SIGKILL: out of memory?)" if exc.returncode == -9 else f"exit status {exc.returncode}"
            last = exc.stderr.strip().splitlines()[-1] if exc.stderr and exc.stderr.strip() else ""
            row = {"n": n, "error": f"{reason} {last}".strip()}
        rows.append(row)
        if "wall_s" in row:
            print(f"n={n:>3}  dofs={row['dofs']:>7}  contacts={row['contacts']:>5}  "
                  f"wall={row['wall_s']:8.2f} s  peak={row['peak_rss_mb']:8.0f} MB", flush=True)
        else:
            print(f"n={n:>3}  {row}", flush=True)
    done = [r for r in rows if "wall_s" in r]
    exponent = last_pair = None
    flops_exponents = {}
    if len(done) >= 2:
        log_dofs, log_wall = np.log([r["dofs"] for r in done]), np.log([r["wall_s"] for r in done])
        exponent = float(np.polyfit(log_dofs, log_wall, 1)[0])
        # the fit is flattened by fixed costs at the small sizes; the slope of the
        # two largest sizes is closer to the asymptotic order
        last_pair = float((log_wall[-1] - log_wall[-2]) / (log_dofs[-1] - log_dofs[-2]))
        print(f"time ~ dofs^{exponent:.2f} over {len(done)} sizes; dofs^{last_pair:.2f} between the two largest")
        for key, what in (("factor_flops", "factorisation + W"), ("plain_factor_flops", "plain nested dissection")):
            log_flops = np.log([r[key] for r in done])
            flops_exponents[key] = float(np.polyfit(log_dofs, log_flops, 1)[0])
            print(f"flops of {what}: " + " / ".join(f"{r[key]:.3g}" for r in done)
                  + f" ~ dofs^{flops_exponents[key]:.2f}")
    result = {"rows": rows, "exponent": exponent, "exponent_two_largest": last_pair, "flops_exponents": flops_exponents}
    path = write_results("scaling", result)
    print(f"wrote {path}")
    return result


if __name__ == "__main__":
    main()
