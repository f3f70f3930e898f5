"""Wall time of the paper case (sect. 9) with a phase breakdown, and the ratio of a
load step to one "assembly + sparse factorisation + solve" of the same stiffness
matrix, measured in the same run (the figure that stays meaningful on a noisy
machine).

    python benchmarks/paper_case.py [--case 3] [--elements 20 20 5] [--method newton]

Prints a table and writes ``benchmarks/results/paper_case.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from _common import write_results
from fe_contact import SolverOptions, initial_state, step
from fe_contact.fem.elasticity import internal_force_and_tangent
from fe_contact.linalg.cholesky import factorise
from pushplan.config import load_scenario
from pushplan.resources import scenario_path


def reference_cost(model, repeats: int = 3) -> float:
    """Best time of one tangent assembly + sparse factorisation (the solver's
    multifrontal Cholesky, without the flexibility matrix) + one solve."""
    U = np.zeros((model.mesh.n_nodes, 3))
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        f, K, _ = internal_force_and_tangent(model.geometry, model.mesh.elements, U, model.material, model.pattern)
        factorise(model.factor_structure, K.data).solve(np.ones(model.free_dofs.size))
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", type=int, default=3, choices=(1, 2, 3))
    parser.add_argument("--elements", type=int, nargs=3, default=None)
    parser.add_argument("--method", default="newton", choices=("newton", "uzawa"))
    parser.add_argument("--no-reuse", action="store_true", help="full Newton (tangent every iteration)")
    args = parser.parse_args(argv)

    scenario = load_scenario(scenario_path(f"paper_case{args.case}.toml"))
    options = SolverOptions(local_method=args.method, reuse_tangent=not args.no_reuse)
    scenario = dataclasses.replace(scenario, solver=options)
    model = scenario.model(elements=tuple(args.elements) if args.elements else None)
    ref = reference_cost(model)

    state = initial_state(model)
    rows = []
    t0 = time.perf_counter()
    for cmd in scenario.commands:
        state, rep = step(model, state, cmd)
        rows.append({
            "step": rep.step_index, "converged": rep.converged, "wall_s": rep.wall_time,
            "ratio_to_reference": rep.wall_time / ref, "newton_iterations": rep.newton_iterations,
            "tangent_updates": rep.tangent_updates, "contact_iterations": rep.contact_iterations,
            **{f"{k}_s": v for k, v in rep.timings.items()},
        })
        if not rep.converged:
            break
    total = time.perf_counter() - t0

    print(f"paper case {args.case}: {model.mesh.n_elements} hex8, {model.mesh.n_dofs} dofs, "
          f"{model.n_contacts} contact nodes, local method {args.method}, reuse tangent {not args.no_reuse}")
    print(f"reference (assembly + factorisation + solve): {ref:.3f} s")
    head = ("step", "wall s", "ratio", "newton", "W", "contact", "assembly", "tangent", "local", "solve")
    print(" ".join(f"{h:>9}" for h in head))
    for r in rows:
        print(" ".join(f"{v:>9}" for v in (
            r["step"], f"{r['wall_s']:.2f}", f"{r['ratio_to_reference']:.1f}", r["newton_iterations"],
            r["tangent_updates"], r["contact_iterations"], f"{r['assembly_s']:.2f}", f"{r['tangent_s']:.2f}",
            f"{r['local_s']:.2f}", f"{r['solve_s']:.2f}")))
    print(f"total {total:.2f} s")
    result = {
        "case": args.case, "elements": list(model.mesh.divisions), "n_dofs": model.mesh.n_dofs,
        "local_method": args.method, "reuse_tangent": not args.no_reuse,
        "reference_s": ref, "total_s": total, "steps": rows,
    }
    path = write_results("paper_case", result)
    print(f"wrote {path}")
    return result


if __name__ == "__main__":
    main()
