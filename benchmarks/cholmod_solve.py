"""One full solve ``K_ff x = b`` with our multifrontal factor against CHOLMOD's on the
same matrix (issue 21: "one full solve with our factor vs CHOLMOD's").

Needs scikit-sparse (a benchmark-only dependency, not the package's: ``pip install
scikit-sparse==0.4.16`` with Debian's ``libsuitesparse-dev``).  For each block
``n x n x n/2`` (the sizes of ``scaling.py``: 8 18 32 52 give 1.2e3 to 2.3e5 dofs) it
builds the tangent at rest, factorises ``K_ff`` both ways, checks the two solutions agree,
and times one solve (forward + backward substitution, one right-hand side) and the
factorisation, alternating the two codes, medians of ``--repeat``.  One BLAS thread.

    python benchmarks/cholmod_solve.py [--sizes 18 32] [--repeat 7]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from _common import write_results
from fe_contact import Friction, Material, Model, SolverOptions, block_mesh
from fe_contact.linalg.cholesky import factorise
from fe_contact.fem.elasticity import internal_force_and_tangent


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def compare(n: int, repeat: int) -> dict:
    from sksparse.cholmod import cholesky

    model = Model(block_mesh((0.02, 0.02, 0.01), (n, n, max(1, n // 2))), Material(210e9, 0.3),
                  Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions())
    U = np.zeros((model.mesh.n_nodes, 3))
    _, K, _ = internal_force_and_tangent(model.geometry, model.mesh.elements, U, model.material, model.pattern)
    free = model.free_dofs
    K_ff = K[free][:, free].tocsc()
    b = np.random.default_rng(0).standard_normal(free.size)
    ours = factorise(model.factor_structure, K.data)
    theirs = cholesky(K_ff)
    x_ours, x_theirs = ours.solve(b), theirs(b)
    agree = float(np.linalg.norm(x_ours - x_theirs) / np.linalg.norm(x_theirs))
    solve_ours = median_time(lambda: ours.solve(b), repeat)
    solve_theirs = median_time(lambda: theirs(b), repeat)
    factor_ours = median_time(lambda: factorise(model.factor_structure, K.data), max(1, repeat // 3))
    factor_theirs = median_time(lambda: cholesky(K_ff), max(1, repeat // 3))
    return {"n": n, "dofs": int(free.size), "parts": int(model.factor_structure.n_parts),
            "relative_difference": agree, "solve_ours_s": solve_ours, "solve_cholmod_s": solve_theirs,
            "solve_ratio": solve_ours / solve_theirs, "factorise_ours_s": factor_ours,
            "factorise_cholmod_s": factor_theirs, "factorise_ratio": factor_ours / factor_theirs}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[18, 32])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    rows = []
    with threadpool_limits(1, user_api="blas"):
        for n in args.sizes:
            row = compare(n, args.repeat)
            rows.append(row)
            print(f"n {n}: {row['dofs']} free dofs, {row['parts']} parts; solutions agree to "
                  f"{row['relative_difference']:.1e}; one solve ours {row['solve_ours_s'] * 1e3:.1f} ms, CHOLMOD "
                  f"{row['solve_cholmod_s'] * 1e3:.1f} ms (ratio {row['solve_ratio']:.2f}); factorisation ours "
                  f"{row['factorise_ours_s']:.2f} s, CHOLMOD {row['factorise_cholmod_s']:.2f} s "
                  f"(ratio {row['factorise_ratio']:.2f}; ours also leaves the contact block for W)", flush=True)
    print(f"wrote {write_results('cholmod_solve', {'sizes': rows})}")


if __name__ == "__main__":
    main()
