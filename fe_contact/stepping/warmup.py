"""Loading the compiled kernels before a timed loop.

The per-contact kernels (cone projection, Alart-Curnier, the paper's Gauss-Seidel
Uzawa sweep) and the multifrontal extend-add are compiled ahead of time (Cython, built
at install: ``fe_contact/*/_kernels.pyx``), so a first call compiles and loads nothing;
until 2026-11-25 they were numba functions whose first call in a process cost 0.1-1.4 s.
What a first step still pays once is small (the first calls into numpy and LAPACK:
``warm_up`` takes 0.015 s against 0.011 s for a second call, measured on the 2-core
machine). A program with a rate to keep (a control loop, a co-simulation) may call
:func:`warm_up` once at start-up so that its first period does not pay for it. The
results of later steps are the same with or without it.
"""

from __future__ import annotations

import time

import numpy as np

from ..fem.elasticity import Material
from ..contact.local_solver import solve_local
from ..fem.mesh import block_mesh
from .model import Command, Friction, Model, SolverOptions, initial_state
from .step import step


def warm_up() -> float:
    """Load every compiled kernel: the local solvers on one sliding contact and a press
    and a push of a 4 x 4 x 2 block (the factorisation's extend-add). Returns the
    seconds it took."""
    t0 = time.perf_counter()
    for method in ("newton", "uzawa"):
        solve_local(np.eye(3), np.array([[-1.0, 0.5, 0.5]]), 0.3, 0.05, method=method)
    model = Model(block_mesh((0.02, 0.02, 0.01), (4, 4, 2)), Material(210e9, 0.3), Friction(0.3, 0.05, 0.0),
                  quadrature=2, options=SolverOptions())
    state, _ = step(model, initial_state(model), Command(dz=-1e-4))
    step(model, state, Command(dx=1e-5), consume=True)
    return time.perf_counter() - t0
