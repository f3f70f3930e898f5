"""Iterations, time and residual of every local contact solver (``solve_local``) on
the three FCLIB problems of ``tests/data/fclib``, a random 441-contact anisotropic
problem and a real FE flexibility problem: the first local problem of load step 2
of the paper's case 3 (sect. 9), captured from ``fe_contact.stepping.step``.

    python benchmarks/local_solvers.py [--elements 20 20 5] [--uzawa-max-iter N]

Prints a table and writes ``benchmarks/results/local_solvers.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from _common import write_results
from fe_contact import initial_state, step
from fe_contact.io.fclib import read_local_problem
from fe_contact.contact.local_solver import METHODS, solve_local
from pushplan.config import load_scenario

ROOT = Path(__file__).resolve().parents[1]
FCLIB = ROOT / "tests" / "data" / "fclib"  # copy of ../shared/fclib
FCLIB_FILES = {
    "fclib boxes": "local_problem_test.hdf5",
    "fclib capsules": "Capsules-i125-1213.hdf5",
    "fclib lmgc": "LMGC_100_PR_PerioBox-i00361-60-03000.hdf5",
}
RANDOM_CONTACTS = 441  # the lower face of the paper's 20 x 20 mesh
MAX_RATIO = 50.0


def random_problem(nc: int, seed: int = 0) -> dict:
    """FE-like SPD ``W = A A^T / n + 0.1 I``, per-contact ``mu_x / mu_y`` up to ``MAX_RATIO``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((3 * nc, 3 * nc))
    q = rng.standard_normal((nc, 3))
    q[:, 0] -= 0.5
    mu_x = rng.uniform(0.1, 0.8, nc)
    mu_y = mu_x / rng.uniform(1.0, MAX_RATIO, nc)
    return dict(W=A @ A.T / (3 * nc) + 0.1 * np.eye(3 * nc), q=q, mu_x=mu_x, mu_y=mu_y)


def fe_step2_problem(elements) -> tuple[dict, dict]:
    """``(W, q, mu_x, mu_y, r0, tol)`` of the first ``solve_local`` call of step 2, and facts.

    Step 1 (compression 0.1 mm) is solved with the Newton local method; then
    ``fe_contact.stepping.newton.solve_local`` is wrapped to record its arguments.
    """
    scenario = load_scenario(ROOT / "scenarios" / "paper_case3.toml")
    model = scenario.model(elements=tuple(elements) if elements else None)
    t0 = time.perf_counter()
    state, rep = step(model, initial_state(model), scenario.commands[0])
    if not rep.converged:
        raise RuntimeError(f"step 1 did not converge: {rep.message}")
    module = sys.modules["fe_contact.stepping.newton"]
    original = module.solve_local
    calls = []

    def recording(W, q, mu_x, mu_y, **kwargs):
        calls.append(dict(W=np.array(W), q=np.array(q), mu_x=mu_x, mu_y=mu_y,
                          r0=np.array(kwargs["r0"]), tol=kwargs["tol"]))
        return original(W, q, mu_x, mu_y, **kwargs)

    module.solve_local = recording
    try:
        _, rep2 = step(model, state, scenario.commands[1])
    finally:
        module.solve_local = original
    facts = {
        "scenario": "paper_case3", "elements": list(model.mesh.divisions),
        "quadrature": model.quadrature, "contacts": model.n_contacts,
        "step2_converged": rep2.converged, "step2_local_calls": len(calls),
        "captured_call": 0, "build_time_s": time.perf_counter() - t0,
        "scaling": "W and q divided by the mean diagonal of W, as fe_contact.stepping.step does",
    }
    return calls[0], facts


def run(name: str, problem: dict, method: str, tol: float, max_iter, r0=None) -> dict:
    t0 = time.perf_counter()
    sol = solve_local(problem["W"], problem["q"], problem["mu_x"], problem["mu_y"],
                      method=method, tol=tol, max_iter=max_iter, r0=r0)
    return {
        "problem": name, "contacts": int(np.shape(problem["q"])[0]), "method": method,
        "start": "cold" if r0 is None else "warm", "tol": tol,
        "iterations": int(sol.iterations), "time_s": time.perf_counter() - t0,
        "residual": float(sol.residual), "converged": bool(sol.converged),
    }


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", type=int, nargs=3, default=None,
                        help="mesh of the FE problem (default: the paper's 20 20 5)")
    parser.add_argument("--tol", type=float, default=1e-8, help="residual target (FCLIB and random)")
    parser.add_argument("--uzawa-max-iter", type=int, default=None,
                        help="Uzawa sweep limit (default: the solver's 20000)")
    args = parser.parse_args(argv)
    limits = {m: (None if m == "newton" else args.uzawa_max_iter) for m in METHODS}

    rows = []
    for name, file in FCLIB_FILES.items():
        p = read_local_problem(FCLIB / file)
        problem = dict(W=p.W, q=p.q, mu_x=p.mu_x, mu_y=p.mu_y)
        rows += [run(name, problem, m, args.tol, limits[m]) for m in METHODS]
    problem = random_problem(RANDOM_CONTACTS)
    rows += [run(f"random {RANDOM_CONTACTS}", problem, m, args.tol, limits[m]) for m in METHODS]
    fe, facts = fe_step2_problem(args.elements)
    for r0 in (fe["r0"], None):
        rows += [run("FE step 2", fe, m, fe["tol"], limits[m], r0=r0) for m in METHODS]

    print(f"FE problem: paper case 3, {facts['elements']} hex8, quadrature {facts['quadrature']}, "
          f"{facts['contacts']} contacts, first of {facts['step2_local_calls']} local solves of step 2 "
          f"(built in {facts['build_time_s']:.1f} s)")
    head = f"{'problem':<16}{'nc':>5}  {'method':<13}{'start':<6}{'iter':>7}{'time s':>9}{'residual':>11}  conv"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['problem']:<16}{r['contacts']:>5}  {r['method']:<13}{r['start']:<6}{r['iterations']:>7}"
              f"{r['time_s']:>9.3f}{r['residual']:>11.2e}  {r['converged']}")
    payload = {"tol": args.tol, "uzawa_max_iter": args.uzawa_max_iter, "fe_problem": facts, "rows": rows}
    path = write_results("local_solvers", payload)
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
