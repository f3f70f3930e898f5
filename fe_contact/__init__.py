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
from .contact.friction import MU_MAX, local_frame, project_elliptic_cone
from .fem.loads import GRAVITY, Gripper
from .contact.bodies import FOOTPRINT_SHAPES, Footprint
from .contact.local_solver import solve_local
from .fem.finite_strain import AUTO_HEX8_POISSON, ELEMENTS
from .fem.material import LAWS
from .fem.mesh import BlockMesh, block_mesh, surface_quads
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
from .stepping.model import LOCAL_METHODS
from .stepping.pose import ZERO_MOTION, face_centroid_displacement, planar_yaw, twist_angle, wrap_angle
from .stepping.command import LetGo, PadLoad
from .stepping.predictor import StepGuess
from .stepping.release import ERROR_TOL_REMOVED, Release, ReleaseSchedule, Rest, rest_check
from .stepping.adjoint import RolloutGradient, rollout_gradient
from .stepping.derivative_check import check_derivatives
from .stepping.derivatives import PARAMETERS, RolloutDerivatives, applicable_parameters, rollout_derivatives
from .stepping.sequence import StepSequence, release_to_rest, run, run_release
from .stepping.step import step
from .stepping.warmup import warm_up
from .linalg.threads import limit_blas_threads

limit_blas_threads()  # one BLAS thread unless the user chose (fe_contact.linalg.threads)


def __getattr__(name):
    """``write_local_problem`` (FCLIB HDF5, :mod:`fe_contact.io.fclib`) on first use: it imports h5py."""
    if name == "write_local_problem":
        from .io.fclib import write_local_problem
        return write_local_problem
    raise AttributeError(f"module 'fe_contact' has no attribute {name!r}")

__all__ = [
    "applicable_parameters",
    "AUTO_HEX8_POISSON",
    "block_mesh",
    "BlockMesh",
    "build_model",
    "check_derivatives",
    "Command",
    "ELEMENTS",
    "face_centroid_displacement",
    "Footprint",
    "FOOTPRINT_SHAPES",
    "Friction",
    "GRAVITY",
    "Gripper",
    "MU_MAX",
    "initial_state",
    "IterLog",
    "LAWS",
    "local_frame",
    "LOCAL_METHODS",
    "Material",
    "Model",
    "NodeStatus",
    "PARAMETERS",
    "planar_yaw",
    "project_elliptic_cone",
    "Release",
    "release_to_rest",
    "LetGo",
    "PadLoad",
    "ERROR_TOL_REMOVED",
    "ReleaseSchedule",
    "Rest",
    "rest_check",
    "rollout_derivatives",
    "rollout_gradient",
    "RolloutDerivatives",
    "RolloutGradient",
    "run",
    "run_release",
    "solve_local",
    "SolverOptions",
    "State",
    "Status",
    "step",
    "StepReport",
    "StepGuess",
    "StepSequence",
    "surface_quads",
    "TangentCache",
    "twist_angle",
    "warm_up",
    "wrap_angle",
    "write_local_problem",
    "ZERO_MOTION",
]
