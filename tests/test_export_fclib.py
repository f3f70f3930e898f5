"""``pushplan simulate --export-fclib``: the exported FCLIB files hold the step's
local contact problem and its solution, and any FCLIB reader/solver recovers it."""

import h5py
import numpy as np

from fe_contact.io.fclib import read_local_problem
from fe_contact.contact.local_solver import natural_map_residual, solve_local
from pushplan.cli import main

RESIDUAL_TOL = 1e-8

SCENARIO = """
name = "export_test"
[block]
size = [0.02, 0.02, 0.01]
elements = [3, 3, 1]
quadrature = 2
[material]
young = 210e9
poisson = 0.3
[friction]
mu_x = 0.3
mu_y = 0.05
angle_deg = 20.0
[[load]]
dz = -1e-4
[[load]]
distance = 3.2e-4
direction_deg = 45.0
"""


def test_export_fclib_writes_solvable_problems(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO)
    fclib_dir = tmp_path / "fclib"
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "out"), "--quiet", "--no-recording",
                 "--export-fclib", str(fclib_dir)]) == 0
    files = sorted(fclib_dir.glob("step_*.hdf5"))
    assert [f.name for f in files] == ["step_001.hdf5", "step_002.hdf5"]
    for f in files:
        prob = read_local_problem(f)
        assert prob.n_contacts == 16
        np.testing.assert_allclose(prob.mu_x, 0.3)
        np.testing.assert_allclose(prob.mu_y, 0.05)
        np.testing.assert_allclose(prob.angle, np.radians(20.0))
        # the stored solution solves the stored problem ...
        u = (prob.W @ prob.r_ref.ravel()).reshape(-1, 3) + prob.q
        assert natural_map_residual(prob.r_ref, u, prob.q, prob.mu_x, prob.mu_y) < RESIDUAL_TOL
        # ... and the plain isotropic FCLIB part, solved as any FCLIB tool would, maps back to it
        with h5py.File(f) as h:
            W = np.zeros((48, 48))
            g = h["fclib_local/W"]
            p, i, x = g["p"][:], g["i"][:], g["x"][:]
            for row in range(48):
                W[row, i[p[row]:p[row + 1]]] = x[p[row]:p[row + 1]]
            q = h["fclib_local/vectors/q"][:].reshape(-1, 3)
            mu = h["fclib_local/vectors/mu"][:]
        iso = solve_local(W, q, mu, mu, method="newton", tol=1e-12)
        assert iso.converged
        r = iso.r * np.column_stack([np.ones(16), prob.mu_x, prob.mu_y])
        np.testing.assert_allclose(r, prob.r_ref, atol=1e-7 * np.abs(prob.r_ref).max())
