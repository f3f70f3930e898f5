"""Solve FCLIB local problems with Siconos (outside reference) and with our local
solvers, and compare the reactions.

Siconos is not a dependency: Debian's ``python3-siconos`` lives in the system
Python, which has no h5py, so this script (run with the project's Python) reads
each file with :func:`fe_contact.fclib.read_local_problem`, hands the plain
isotropic FCLIB data ``(W', q', mu')`` to ``/usr/bin/python3`` as ``.npz``, and
runs Siconos' NSGS there (``fc3d_driver`` with ``SICONOS_FRICTION_3D_NSGS``).

    python benchmarks/siconos_compare.py FILE.hdf5 [FILE.hdf5 ...] [--system-python /usr/bin/python3]

Typical use: ``pushplan simulate scenarios/paper_case3.toml --out out/s
--export-fclib out/fclib`` then ``python benchmarks/siconos_compare.py
out/fclib/*.hdf5``.  Prints a table and writes
``benchmarks/results/siconos_compare.json``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import write_results
from fe_contact.fclib import read_local_problem
from fe_contact.local_solver import natural_map_residual, solve_local

SICONOS = r"""
import json, sys, time
import numpy as np
import siconos.numerics as sn
d = np.load(sys.argv[1])
W, q, mu = d["W"], d["q"], d["mu"]
n = mu.size
problem = sn.FrictionContactProblem(3, n, W, q, mu)
options = sn.SolverOptions(sn.SICONOS_FRICTION_3D_NSGS)
options.iparam[sn.SICONOS_IPARAM_MAX_ITER] = 100000
options.dparam[sn.SICONOS_DPARAM_TOL] = float(sys.argv[3])
r, u = np.zeros(3 * n), np.zeros(3 * n)
t0 = time.perf_counter()
info = sn.fc3d_driver(problem, r, u, options)
np.savez(sys.argv[2], r=r, u=u, info=info, time=time.perf_counter() - t0,
         iterations=options.iparam[sn.SICONOS_IPARAM_ITER_DONE], error=options.dparam[sn.SICONOS_DPARAM_RESIDU])
"""

TOL = 1e-10


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--system-python", default="/usr/bin/python3")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.files:
            prob = read_local_problem(path)
            n = prob.n_contacts
            D = np.column_stack([np.ones(n), prob.mu_x, prob.mu_y])
            iso = np.all(prob.mu_x == prob.mu_y)
            # the isotropic FCLIB form any FCLIB tool solves
            Ds = np.ones_like(D) if iso else np.where(D > 0, D, 0.0)
            d = Ds.ravel()
            Wi, qi = prob.W * d[:, None] * d[None, :], prob.q * Ds
            mui = prob.mu_x if iso else np.where((prob.mu_x == 0) & (prob.mu_y == 0), 0.0, 1.0)
            np.savez(Path(tmp) / "in.npz", W=Wi, q=qi.ravel(), mu=mui)
            proc = subprocess.run([args.system_python, "-c", SICONOS, str(Path(tmp) / "in.npz"),
                                   str(Path(tmp) / "out.npz"), str(TOL)], capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{path.name}: Siconos failed: {proc.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
                rows.append({"file": str(path), "siconos_error": proc.stderr.strip()[-500:]})
                continue
            s = np.load(Path(tmp) / "out.npz")
            r_sic = s["r"].reshape(-1, 3) * Ds
            u_sic = (prob.W @ r_sic.ravel()).reshape(-1, 3) + prob.q
            row = {"file": str(path), "contacts": n,
                   "siconos": {"info": int(s["info"]), "iterations": int(s["iterations"]),
                               "time_s": float(s["time"]),
                               "residual": natural_map_residual(r_sic, u_sic, prob.q, prob.mu_x, prob.mu_y)}}
            for method in ("newton", "uzawa"):
                t0 = time.perf_counter()
                sol = solve_local(prob.W, prob.q, prob.mu_x, prob.mu_y, method=method, tol=TOL)
                row[method] = {"converged": sol.converged, "iterations": sol.iterations,
                               "time_s": time.perf_counter() - t0, "residual": sol.residual,
                               "max_r_diff_vs_siconos": float(np.abs(sol.r - r_sic).max() / max(np.abs(r_sic).max(), 1e-300))}
            rows.append(row)
            print(f"{path.name:>40} n={n:>4}  siconos NSGS: {row['siconos']['iterations']:>6} it "
                  f"{row['siconos']['time_s']:7.3f} s res {row['siconos']['residual']:.1e}  |  "
                  + "  ".join(f"{m}: {row[m]['iterations']:>5} it {row[m]['time_s']:7.3f} s res {row[m]['residual']:.1e} "
                              f"dr {row[m]['max_r_diff_vs_siconos']:.1e}" for m in ("newton", "uzawa")), flush=True)
    path = write_results("siconos_compare", {"tolerance": TOL, "rows": rows})
    print(f"wrote {path}")
    return {"rows": rows}


if __name__ == "__main__":
    main()
