"""Our local solvers against Siconos (outside reference) on the same problems, in one run:
time ratios and agreement of the reactions.

Problems (all solved from ``r = 0`` to the natural-map residual ``TOL``):

* the shared FCLIB LMGC problem (``tests/data/fclib``) and any FCLIB files given;
* the paper-mesh step problems: the first local problem of each push step of
  paper case 3 (20 x 20 x 5 hex8, 3^3 Gauss points, 441 contacts), captured
  from ``fe_contact.stepping.step``;
* the large-friction problems of issue 21: isotropic ``mu`` in {4, 10, 100,
  1000}, the first local problem of the press and of the bonded step (press,
  then a 0.1 um push) of the 10 x 10 x 4 block.

Siconos is not a dependency: Debian's ``python3-siconos`` lives in the system
Python, which has no h5py, so the problems go to ``/usr/bin/python3`` as
``.npz`` and one process there runs NSN_AC (semismooth Newton on Alart-Curnier)
and NSGS on each.  An anisotropic problem is handed over in the isotropic form
our Newton solves, ``FC(D W D, D q, mu)`` with ``mu = max(mu_x, mu_y)`` and
``D = diag(1, mu_x / mu, mu_y / mu)`` (``D = I`` for isotropic contacts).

    python benchmarks/siconos_compare.py [FILE.hdf5 ...] [--elements 20 20 5] [--system-python /usr/bin/python3]

Prints a table and writes ``benchmarks/results/siconos_compare.json``; the
ratio is our time over the faster of the two Siconos solvers.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh, initial_state, step
from fe_contact.io.fclib import read_local_problem
from fe_contact.contact.local_solver import natural_map_residual, solve_local

ROOT = Path(__file__).resolve().parents[1]
LMGC = ROOT / "tests" / "data" / "fclib" / "LMGC_100_PR_PerioBox-i00361-60-03000.hdf5"
TOL = 1e-10
LARGE_MUS = (4.0, 10.0, 100.0, 1000.0)
OURS = ("newton", "uzawa")

SICONOS = r"""
import json, sys, time
import numpy as np
import siconos.numerics as sn
names = json.loads(open(sys.argv[1]).read())
tol = float(sys.argv[2])
out = {}
for name, path in names.items():
    d = np.load(path)
    W, q, mu = d["W"], d["q"], d["mu"]
    n = mu.size
    for solver, sid, max_iter in (("NSN_AC", sn.SICONOS_FRICTION_3D_NSN_AC, 500),
                                  ("NSGS", sn.SICONOS_FRICTION_3D_NSGS, 100000)):
        problem = sn.FrictionContactProblem(3, n, W, q, mu)
        options = sn.SolverOptions(sid)
        options.iparam[sn.SICONOS_IPARAM_MAX_ITER] = max_iter
        options.dparam[sn.SICONOS_DPARAM_TOL] = tol
        r, u = np.zeros(3 * n), np.zeros(3 * n)
        t0 = time.perf_counter()
        info = sn.fc3d_driver(problem, r, u, options)
        elapsed = time.perf_counter() - t0
        np.save(path + "." + solver + ".npy", r)
        out[name + "|" + solver] = dict(info=int(info), time_s=elapsed,
                                        iterations=int(options.iparam[sn.SICONOS_IPARAM_ITER_DONE]))
print(json.dumps(out))
"""


def _captured_steps(model, commands) -> list:
    """The first local problem ``(W, q)`` of each step of ``commands`` (steps run in turn)."""
    out, state = [], initial_state(model)
    for cmd in commands:
        calls = []
        state, rep = step(model, state, cmd, lambda W, q, local: calls.append((np.array(W), np.array(q))))
        if not rep.converged:
            raise RuntimeError(f"{cmd}: {rep.message}")
        out.append(calls[0])
    return out


def problems(files, elements) -> dict:
    """name -> dict(W, q, mu_x, mu_y)."""
    from pushplan.config import load_scenario

    out = {}
    for path in [LMGC, *files]:
        p = read_local_problem(path)
        out[f"fclib {Path(path).stem[:24]}"] = dict(W=p.W, q=p.q, mu_x=p.mu_x, mu_y=p.mu_y)
    scenario = load_scenario(ROOT / "scenarios" / "paper_case3.toml")
    model = scenario.model(elements=tuple(elements) if elements else None)
    fr = model.friction
    for k, (W, q) in enumerate(_captured_steps(model, scenario.commands)):
        if k:  # the push steps
            out[f"paper case 3 step {k + 1}"] = dict(W=W, q=q, mu_x=fr.mu_x, mu_y=fr.mu_y)
    for mu in LARGE_MUS:
        block = Model(mesh=block_mesh((0.02, 0.02, 0.01), (10, 10, 4)), material=Material(210e9, 0.3),
                      friction=Friction(mu, mu, 0.0), quadrature=2, options=SolverOptions())
        (Wp, qp), (Wb, qb) = _captured_steps(block, [Command(dz=-0.1e-3), Command(dx=0.1e-6)])
        out[f"mu {mu:g} press"] = dict(W=Wp, q=qp, mu_x=mu, mu_y=mu)
        out[f"mu {mu:g} bonded"] = dict(W=Wb, q=qb, mu_x=mu, mu_y=mu)
    return out


def isotropic_form(p) -> tuple:
    """``(D (n, 3), W', q', mu')`` of :mod:`fe_contact.contact.local_solver`'s per-contact scaling."""
    n = p["q"].shape[0]
    mx, my = np.broadcast_to(p["mu_x"], (n,)).astype(float), np.broadcast_to(p["mu_y"], (n,)).astype(float)
    mu = np.maximum(mx, my)
    safe = np.where(mu > 0, mu, 1.0)
    D = np.column_stack([np.ones(n), np.where(mu > 0, mx / safe, 1.0), np.where(mu > 0, my / safe, 1.0)])
    d = D.ravel()
    return D, p["W"] * d[:, None] * d[None, :], (p["q"] * D).ravel(), mu


def run_siconos(probs, system_python, tmp) -> dict:
    names, forms = {}, {}
    for i, (name, p) in enumerate(probs.items()):
        D, W, q, mu = isotropic_form(p)
        path = str(Path(tmp) / f"p{i}.npz")
        np.savez(path, W=W, q=q, mu=mu)
        names[name], forms[name] = path, D
    (Path(tmp) / "names.json").write_text(json.dumps(names))
    proc = subprocess.run([system_python, "-c", SICONOS, str(Path(tmp) / "names.json"), str(TOL)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"Siconos failed: {proc.stderr.strip()[-800:]}")
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    out = {}
    for name, p in probs.items():
        for solver in ("NSN_AC", "NSGS"):
            r = np.load(names[name] + f".{solver}.npy").reshape(-1, 3) * forms[name]
            u = (p["W"] @ r.ravel()).reshape(-1, 3) + p["q"]
            out[name, solver] = dict(info[f"{name}|{solver}"], r=r, u=u,
                                     residual=natural_map_residual(r, u, p["q"], p["mu_x"], p["mu_y"]))
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--elements", type=int, nargs=3, default=None, help="paper mesh (default 20 20 5)")
    parser.add_argument("--system-python", default="/usr/bin/python3")
    args = parser.parse_args(argv)
    probs = problems(args.files, args.elements)
    with tempfile.TemporaryDirectory() as tmp:
        sic = run_siconos(probs, args.system_python, tmp)
    rows = []
    head = (f"{'problem':<26}{'nc':>5} {'NSN_AC s':>9}{'NSGS s':>9} " + " ".join(f"{m + ' s':>9}{'ratio':>7}" for m in OURS)
            + f"  {'max dr, du vs NSN_AC (newton, uzawa)'}")
    print(head + "\n" + "-" * len(head))
    for name, p in probs.items():
        ref = sic[name, "NSN_AC"]
        row = {"problem": name, "contacts": int(p["q"].shape[0]),
               **{s: {k: v for k, v in sic[name, s].items() if k not in ("r", "u")} for s in ("NSN_AC", "NSGS")}}
        ok = [sic[name, s]["time_s"] for s in ("NSN_AC", "NSGS") if sic[name, s]["residual"] <= 10 * TOL]
        fastest = min(ok) if ok else float("nan")
        scale = max(np.abs(ref["r"]).max(), 1e-300)
        for m in OURS:
            solve_local(p["W"], p["q"], p["mu_x"], p["mu_y"], method=m, tol=TOL)  # warm: compiled kernels
            t0 = time.perf_counter()
            sol = solve_local(p["W"], p["q"], p["mu_x"], p["mu_y"], method=m, tol=TOL)
            elapsed = time.perf_counter() - t0
            row[m] = {"converged": sol.converged, "iterations": sol.iterations, "time_s": elapsed,
                      "residual": sol.residual, "ratio_to_faster_siconos": elapsed / fastest,
                      "max_r_diff_vs_nsn_ac": float(np.abs(sol.r - ref["r"]).max() / scale),
                      # u is unique where r is not (a rank-deficient W: the FCLIB problems)
                      "max_u_diff_vs_nsn_ac": float(np.abs(sol.u - ref["u"]).max() / max(np.abs(p["q"]).max(), 1e-300))}
        rows.append(row)
        print(f"{name:<26}{row['contacts']:>5} {row['NSN_AC']['time_s']:>9.3f}{row['NSGS']['time_s']:>9.3f} "
              + " ".join(f"{row[m]['time_s']:>9.3f}{row[m]['ratio_to_faster_siconos']:>7.2f}" for m in OURS)
              + "  " + " ".join(f"{row[m]['max_r_diff_vs_nsn_ac']:.0e},{row[m]['max_u_diff_vs_nsn_ac']:.0e}" for m in OURS)
              + ("" if all(row[m]["converged"] for m in OURS) else "  (ours not converged)")
              + ("" if ref["residual"] <= 10 * TOL else f"  (NSN_AC residual {ref['residual']:.1e})"), flush=True)
    path = write_results("siconos_compare", {"tolerance": TOL, "start": "cold (r = 0)",
                                             "ratio": "our time / the faster Siconos solver that converged",
                                             "rows": rows})
    print(f"wrote {path}")
    return {"rows": rows}


if __name__ == "__main__":
    main()
