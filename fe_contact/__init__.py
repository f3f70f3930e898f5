"""Quasi-static 3D FE contact solver: an elastic St Venant-Kirchhoff hex8 block on a
rigid plane with orthotropic (elliptic) Coulomb friction, solved with the De Saxce
bi-potential projection and an Uzawa-type loop on the contact nodes
(Feng, Hjiaj, de Saxce, Mroz, Comput. Mech. 37:349-361, 2006).

Public API::

    model = Model(block_mesh(size, divisions), Material(E, nu), Friction(mu_x, mu_y, angle))
    state = initial_state(model)
    state, report = step(model, state, Command(dz=-1e-4))
    state, reports = run_release(model, state, Release("lift", 5), step, report)

Beyond the paper: ``Material(E, nu, density)`` adds self-weight (eq. 3 body force),
``Model(..., gripper=Gripper(k_xy, k_yaw))`` a compliant gripper, and
:mod:`fe_contact.release` lets go of the block (``lift`` or ``open``).

This package knows nothing about planning, robots, MuJoCo or rerun.
"""

from .elasticity import Material
from .friction import project_elliptic_cone
from .loads import GRAVITY, Gripper
from .local_solver import solve_local
from .mesh import BlockMesh, block_mesh
from .model import (
    Command,
    Friction,
    IterLog,
    Model,
    NodeStatus,
    SolverOptions,
    State,
    Status,
    StepReport,
    TangentCache,
    build_model,
    initial_state,
)
from .release import Release, ReleaseSchedule, run_release
from .step import run, step
from .warmup import warm_up
from ._threads import limit_blas_threads

limit_blas_threads()  # one BLAS thread unless the user chose (fe_contact._threads)

__all__ = [
    "BlockMesh",
    "Command",
    "Friction",
    "GRAVITY",
    "Gripper",
    "IterLog",
    "Material",
    "Model",
    "NodeStatus",
    "Release",
    "ReleaseSchedule",
    "SolverOptions",
    "State",
    "Status",
    "StepReport",
    "TangentCache",
    "block_mesh",
    "build_model",
    "initial_state",
    "project_elliptic_cone",
    "run",
    "run_release",
    "solve_local",
    "step",
    "warm_up",
]
