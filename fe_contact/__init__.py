"""Quasi-static 3D FE contact solver: an elastic St Venant-Kirchhoff hex8 block on a
rigid plane with orthotropic (elliptic) Coulomb friction, solved with the De Saxce
bi-potential projection and an Uzawa-type loop on the contact nodes
(Feng, Hjiaj, de Saxce, Mroz, Comput. Mech. 37:349-361, 2006).

Public API::

    model = Model(block_mesh(size, divisions), Material(E, nu), Friction(mu_x, mu_y, angle))
    state = initial_state(model)
    state, report = step(model, state, Command(dz=-1e-4))
    state, reports = run_release(model, state, Release("lift", 5), report)

Beyond the paper: ``Material(E, nu, model="neo_hookean")`` a compressible
Neo-Hookean law and ``Model(..., element="fbar")`` an element that does not lock
(docs/materials.md); ``Material(E, nu, density)`` adds self-weight (eq. 3 body force),
``Model(..., gripper=Gripper(k_xy, k_yaw))`` a compliant gripper,
``Model(..., pad=Friction(...))`` a frictional gripper pad (a second contact body,
:mod:`fe_contact.contact.bodies`), and :mod:`fe_contact.stepping.release` lets go of
the block (``lift``, up or up and away) and says whether it settled (``release_to_rest``).

Layers, lowest first (a subpackage imports only from those before it)::

    linalg/    the multifrontal Cholesky factor, BLAS thread policy
    fem/       hex8 element and quadrature, mesh, assembly, St Venant-Kirchhoff
               elasticity (eq. 1-5), loads (self-weight, eq. 3; gripper springs)
    contact/   elliptic friction cone and its projection (eq. 13-45), local
               solvers on the contact nodes (Newton / Alart-Curnier, Uzawa)
    io/        FCLIB HDF5 interchange of local problems
    stepping/  Model / State, predictor, Newton loop with the flexibility
               matrix (sect. 8, Box 3/4), measurement, compliant gripper,
               release, ``step`` and the one loop over steps (``run``)

This package knows nothing about planning, robots, MuJoCo or rerun.
"""

from .fem.elasticity import Material
from .contact.friction import local_frame, project_elliptic_cone
from .fem.loads import GRAVITY, Gripper
from .contact.local_solver import solve_local
from .fem.mesh import BlockMesh, block_mesh
from .stepping.model import (
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
from .stepping.command import PadLoad
from .stepping.release import Release, ReleaseSchedule, Rest, rest_check
from .stepping.adjoint import RolloutGradient, rollout_gradient
from .stepping.derivatives import RolloutDerivatives, check_derivatives, rollout_derivatives
from .stepping.sequence import StepSequence, release_to_rest, run, run_release
from .stepping.step import step
from .stepping.warmup import warm_up
from .linalg.threads import limit_blas_threads

limit_blas_threads()  # one BLAS thread unless the user chose (fe_contact.linalg.threads)

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
    "PadLoad",
    "ReleaseSchedule",
    "Rest",
    "RolloutDerivatives",
    "RolloutGradient",
    "SolverOptions",
    "State",
    "Status",
    "StepReport",
    "StepSequence",
    "TangentCache",
    "block_mesh",
    "build_model",
    "check_derivatives",
    "initial_state",
    "local_frame",
    "project_elliptic_cone",
    "release_to_rest",
    "rest_check",
    "rollout_derivatives",
    "rollout_gradient",
    "run",
    "run_release",
    "solve_local",
    "step",
    "warm_up",
]
