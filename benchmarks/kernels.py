"""Per-call time and results of fe_contact's four compiled kernels, this tree against
the tree before, in one run (issue 32 item 3: the numba kernels compiled ahead of time
as Cython).

- the cone projection ``_project`` and the Alart-Curnier function ``alart_curnier``
  (kernel and its numpy around it) on the 81 contacts of a planning mesh;
- one Gauss-Seidel sweep of the paper's Uzawa (``_gauss_seidel_sweeps``) on the 441
  contacts of the paper's 20 x 20 mesh (a random SPD ``W``);
- the multifrontal factorisation ``factorise`` of the tangent at rest of an
  ``n x n x n/2`` block, and the part of it spent in the extend-add (``_extend_add``
  timed call by call).

Each tree runs in its own process with its own ``.venv/bin/python`` from its root (the
tree before needs numba in its venv), the trees alternating ``--repeat`` times; a
kernel's first call (numba's load) is made before timing.  The outputs of every
kernel on the same inputs are compared bit for bit between the trees.  Medians;
load average before and after.  Writes ``benchmarks/results/kernels.json``.

    git worktree add ../aot-base d7aea18 && ln -s /path/to/a/venv/with/numba ../aot-base/.venv
    .venv/bin/python benchmarks/kernels.py --base ../aot-base [--repeat 3] [--n 24]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import write_results

ROOT = Path(__file__).resolve().parents[1]

WORKER = r"""
import json, sys, time
import numpy as np
from fe_contact import Friction, Material, Model, SolverOptions, block_mesh
from fe_contact.contact import alart_curnier as ac, friction, uzawa
from fe_contact.fem.elasticity import internal_force_and_tangent
from fe_contact.linalg import cholesky

out_json, out_npz, n_mesh = sys.argv[1], sys.argv[2], int(sys.argv[3])
rng = np.random.default_rng(0)


def per_call(fn, calls):
    fn()  # the first call loads a numba kernel
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - t0) / calls)
    return float(np.median(times))


nc = 81
tau = rng.standard_normal((nc, 3))
mx, my = rng.uniform(0.1, 1.0, nc), rng.uniform(0.1, 1.0, nc)
s, qs = rng.standard_normal((nc, 3)), rng.standard_normal((nc, 3))
A = rng.standard_normal((3 * nc, 3 * nc))
W = A @ A.T / (3 * nc) + 0.1 * np.eye(3 * nc)
d, mu, rho = np.ones(3 * nc), rng.uniform(0.1, 1.0, nc), rng.uniform(0.5, 2.0, (nc, 2))
fixed = np.zeros((nc, 3), bool)
ng = 441
B = rng.standard_normal((3 * ng, 3 * ng))
Wg = np.ascontiguousarray(B @ B.T / (3 * ng) + np.eye(3 * ng))
qg = rng.standard_normal((ng, 3)) - [1.0, 0.0, 0.0]
gmx, gmy, grho = rng.uniform(0.1, 1.0, ng), rng.uniform(0.1, 1.0, ng), rng.uniform(0.2, 1.0, ng)
res = {}
res["project_81_us"] = 1e6 * per_call(lambda: friction._project(tau, mx, my), 2000)
res["alart_curnier_81_us"] = 1e6 * per_call(lambda: ac.alart_curnier(s, W, d, qs, mu, rho, fixed), 1000)
rg = np.zeros((ng, 3))
res["gauss_seidel_sweep_441_us"] = 1e6 * per_call(
    lambda: uzawa._gauss_seidel_sweeps(Wg, qg, gmx, gmy, grho, rg.copy(), 1, np.zeros((0, 3, 3))), 20)
model = Model(block_mesh((0.02, 0.02, 0.01), (n_mesh, n_mesh, max(1, n_mesh // 2))), Material(210e9, 0.3),
              Friction(0.3, 0.05, 0.0), quadrature=2, options=SolverOptions())
_, K, _ = internal_force_and_tangent(model.geometry, model.mesh.elements, np.zeros((model.mesh.n_nodes, 3)),
                                     model.material, model.pattern)
kernel, spent = cholesky._extend_add, [0.0]


def timed_extend_add(*args):
    t0 = time.perf_counter()
    kernel(*args)
    spent[0] += time.perf_counter() - t0


cholesky._extend_add = timed_extend_add
cholesky.factorise(model.factor_structure, K.data)  # first call loads the kernel
spent[0] = 0.0
t0 = time.perf_counter()
factor = cholesky.factorise(model.factor_structure, K.data)
res["factorise_s"] = time.perf_counter() - t0
res["extend_add_s"] = spent[0]
res["factorise_dofs"] = int(model.free_dofs.size)
rg = np.zeros((ng, 3))
uzawa._gauss_seidel_sweeps(Wg, qg, gmx, gmy, grho, rg, 3, np.zeros((0, 3, 3)))
np.savez(out_npz, project=friction._project(tau * 10.0 ** rng.integers(-20, 20, (nc, 1)), mx, my),
         ac=np.concatenate([a.ravel() for a in ac.alart_curnier(s, W, d, qs, mu, rho, fixed)]), gauss_seidel=rg,
         root_inverse=factor.root_inverse(), solve=factor.solve(np.linspace(-1.0, 1.0, model.free_dofs.size)))
json.dump(res, open(out_json, "w"))
"""


def run_tree(root: Path, tmp: Path, label: str, n: int, k: int) -> tuple[dict, dict]:
    """One worker process of the tree at ``root``: its figures and its outputs."""
    python = root / ".venv" / "bin" / "python"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1"}
    out_json, out_npz = tmp / f"{label}{k}.json", tmp / f"{label}{k}.npz"
    subprocess.run([str(python), "-c", WORKER, str(out_json), str(out_npz), str(n)], cwd=root, env=env, check=True)
    with np.load(out_npz) as z:
        return json.loads(out_json.read_text()), {name: z[name] for name in z.files}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True, help="checkout of the tree before, with its own .venv")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--n", type=int, default=24, help="elements along x and y of the factorised block")
    args = parser.parse_args(argv)
    trees = {"this": ROOT, args.base.resolve().name: args.base.resolve()}
    load_before, started = os.getloadavg(), time.strftime("%Y-%m-%d %H:%M")
    runs: dict = {label: [] for label in trees}
    outputs: dict = {}
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.repeat):
            for label, root in trees.items():
                figures, outputs[label] = run_tree(root, Path(d), label, args.n, k)
                runs[label].append(figures)
    base = args.base.resolve().name
    identical = {name: bool(np.array_equal(outputs["this"][name].view(np.uint64), outputs[base][name].view(np.uint64)))
                 for name in outputs["this"]}
    median = {label: {key: float(np.median([r[key] for r in rs])) for key in rs[0]} for label, rs in runs.items()}
    ratio = {key: median["this"][key] / median[base][key] for key in median["this"] if key != "factorise_dofs"}
    result = {"started": started, "load_average_before": load_before, "load_average_after": os.getloadavg(),
              "cpus": os.cpu_count(), "repeat": args.repeat, "base": str(args.base.resolve()),
              "median": median, "ratio_this_over_base": ratio, "bit_identical_outputs": identical, "runs": runs}
    for key in ratio:
        print(f"{key:>28}  this {median['this'][key]:10.4g}  {base} {median[base][key]:10.4g}  ratio {ratio[key]:.3f}")
    print(f"factorised {median['this']['factorise_dofs']:.0f} free dofs; outputs bit-identical: {identical}")
    print(f"load average {load_before[0]:.2f} -> {result['load_average_after'][0]:.2f} on {os.cpu_count()} cpus; "
          f"medians of {args.repeat}")
    print(f"wrote {write_results('kernels', result)}")
    if not all(identical.values()):
        sys.exit(1)


if __name__ == "__main__":
    main()
