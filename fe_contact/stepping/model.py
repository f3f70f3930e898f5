"""Static problem description (``Model``), explicit solution state (``State``),
load-step commands and step reports.

The split follows MuJoCo's ``mjModel`` / ``mjData``: a :class:`Model` is immutable
and holds everything precomputed once (mesh, quadrature geometry, sparsity
pattern, contact frames); a :class:`State` is the path-dependent solution after
some load steps.  :func:`fe_contact.stepping.step.step` maps ``(model, state, command)`` to
a new state and a :class:`StepReport` without mutating its inputs, so a planner
can branch from any state.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..fem.assembly import SparsityPattern, sparsity_pattern
from ..fem.elasticity import ElementGeometry, Material, element_geometry
from ..fem.finite_strain import fbar_weight, resolve_element
from ..linalg.cholesky import SupernodalStructure, supernodal_structure
from ..fem.loads import GRAVITY, Gripper, body_force, diagonal_positions, nodal_volumes
from ..fem.mesh import BlockMesh, block_mesh, face_tributary_areas, nested_dissection_parts

from ..contact.bodies import ContactBody, ContactSet, Footprint, horizontal_frame, stack_bodies
from ..contact.friction import MU_MAX, local_frame
from ..contact.local_solver import METHODS as LOCAL_METHODS
from .command import Command, _finite  # noqa: F401  (Command re-exported)
from .report import IterLog, NodeStatus, Status, StepReport  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class Friction:
    """Orthotropic (elliptic) Coulomb friction of the plane.

    Parameters
    ----------
    mu_x, mu_y : float
        Principal friction coefficients along the orthotropy axes ``t_x``, ``t_y``
        (from 0 to ``MU_MAX`` = 1e3 of :mod:`fe_contact.contact.friction`;
        both zero is frictionless contact).
    angle : float
        Angle of ``t_x`` from world x, counter-clockwise, rad.
    """

    mu_x: float
    mu_y: float
    angle: float = 0.0

    def __post_init__(self):
        for name in ("mu_x", "mu_y"):
            v = _finite(name, getattr(self, name))
            if not 0 <= v <= MU_MAX:
                raise ValueError(f"{name} must be finite, >= 0 and <= {MU_MAX:g}, got {v}")
            object.__setattr__(self, name, v)
        object.__setattr__(self, "angle", _finite("angle", self.angle))


@dataclass(frozen=True)
class SolverOptions:
    """Settings of the Newton equilibrium loop and the local contact solver.

    Parameters
    ----------
    local_method : str
        Local contact solver, one of ``LOCAL_METHODS``.  ``"newton"`` (default)
        is the fastest robust one measured (``benchmarks/local_solvers.py``);
        ``"uzawa"`` is the paper's algorithm (node-by-node sweeps with its
        ``rho``); ``"uzawa_jacobi"`` updates all nodes at once (safeguarded),
        kept for comparison.
    local_tol : float
        Natural-map residual tolerance of the local solve (Siconos normalisation).
    local_max_iter : int or None
        Iteration limit of the local solve (None: the method's default, 20000
        Uzawa sweeps or 100 Newton steps).
    newton_tol : float
        Tolerance on the out-of-balance force of the free dofs, relative to the
        largest of the contact and upper-face reaction norms and the step's
        predictor out-of-balance force (which keeps it meaningful when the
        block is lifted off and all forces vanish); a step whose last
        correction is at rounding level of the displacements has converged
        too (its force is what rounding allows).
    newton_max_iter : int
        Iteration limit of the equilibrium loop (a bound on its cost, not a
        convergence test: a loop whose force stops falling ends earlier,
        "stalled at r", :mod:`fe_contact.stepping.newton`).
    path_tol : float
        Tolerance, like ``newton_tol``, of a frictional pad's release's load
        steps to a load above zero (:class:`~fe_contact.stepping.command.PadLoad`,
        their midpoint halves, second halves and split parts): points on the
        unloading path, whose discretisation error is 0.1-1 % of the lag, are
        solved to ``max(newton_tol, path_tol)``; the release's last step to zero
        load, every other step and the rest check keep ``newton_tol``.  Its
        effect on the rest pose is measured (docs/release.md); a derivative
        checked by central differences through a release wants it tight.
    reuse_tangent : bool
        Modified Newton: keep the tangent (its factorisation and the flexibility
        matrix) from iteration to iteration and from step to step, refreshing it
        only when the out-of-balance force contracts by less than
        ``refresh_ratio`` per iteration and the iterations a new tangent would
        save cost more than building it (a size-based estimate, so runs are
        repeatable).  The converged solution is the same to the tolerances; the
        flexibility matrix, the dominant cost, is computed far less often.
    refresh_ratio : float
        Contraction factor of the relative residual above which a reused
        tangent may be recomputed.
    acceleration : int
        Depth of the Anderson acceleration of the modified-Newton loop
        (:mod:`fe_contact.stepping.acceleration`): the differences of the last
        ``acceleration`` iterations mixed into the next iterate; 0 turns it off.
        Convergence is only declared at a plain iterate, so the converged
        solution is the same to the tolerances (tested on and off); it does
        nothing in full Newton or with a frictional pad.
    pad_regularisation : float
        ``beta`` of the regularising springs of a block between the floor and
        a frictional pad (:func:`fe_contact.stepping.held.pad_loading`), as a
        fraction of its shear stiffness; the answer converges as it goes to 0.
    """

    local_method: str = "newton"
    local_tol: float = 1e-10
    local_max_iter: int | None = None
    newton_tol: float = 1e-10
    newton_max_iter: int = 100
    path_tol: float = 1e-5
    reuse_tangent: bool = True
    refresh_ratio: float = 0.2
    pad_regularisation: float = 1e-2
    acceleration: int = 4

    def __post_init__(self):
        if self.local_method not in LOCAL_METHODS:
            raise ValueError(
                f"local_method must be one of {LOCAL_METHODS}, got {self.local_method!r}"
            )
        for name in ("local_tol", "newton_tol", "path_tol"):
            v = _finite(name, getattr(self, name))
            if not 0 < v < 1:
                raise ValueError(f"{name} must be in (0, 1), got {v}")
        v = _finite("refresh_ratio", self.refresh_ratio)
        if not 0 < v < 1:
            raise ValueError(f"refresh_ratio must be in (0, 1), got {v}")
        if not _finite("pad_regularisation", self.pad_regularisation) > 0:
            raise ValueError(f"pad_regularisation must be > 0, got {self.pad_regularisation}")
        v = self.acceleration
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"acceleration must be an integer >= 0, got {v!r}")
        for name in ("local_max_iter", "newton_max_iter"):
            v = getattr(self, name)
            if v is None and name == "local_max_iter":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")


@dataclass(frozen=True)
class Model:
    """Immutable description of the block-on-plane problem.

    Build it with :func:`build_model`.  Derived arrays (quadrature geometry,
    sparsity pattern, dof partition, tributary areas) are computed once here.
    """

    mesh: BlockMesh
    material: Material
    friction: Friction
    quadrature: int = 3
    options: SolverOptions = field(default_factory=SolverOptions)
    gripper: Gripper = field(default_factory=Gripper)
    hold_upper: bool = True
    """False: the upper face is free (a released block), every dof is free."""
    pad: Friction | None = None
    """Friction of the gripper pad on the upper face, a rigid plane in
    unilateral frictional contact with it (:mod:`fe_contact.contact.bodies`);
    None (default): the pad is bonded to the upper face (the paper's
    displacement control)."""
    element: str = "auto"
    """Element formulation (:data:`fe_contact.fem.finite_strain.ELEMENTS`):
    ``"hex8"``, ``"fbar"`` (does not lock as nu -> 0.5), or ``"auto"`` (hex8 up to
    ``poisson = AUTO_HEX8_POISSON``, 0.45, F-bar from ``AUTO_FBAR_POISSON``, 0.48, and
    between them ``"fbar_blend"``, the F-bar family member whose weight rises smoothly
    with nu: :func:`~fe_contact.fem.finite_strain.auto_fbar_weight`); the resolved name
    after construction (its weight: ``geometry.fbar_weight``)."""
    footprint: Footprint | None = None
    """The pad's footprint on the upper face (:class:`~fe_contact.contact.bodies.Footprint`):
    only the upper-face nodes under it are held (bonded pad) or pad contacts
    (frictional pad), the rest of the face is free; None (default): the whole
    face.  Rotations stay about the face's centre (:attr:`upper_centre`)."""
    held_nodes: np.ndarray = field(init=False, repr=False)
    """(n_held,) upper-face nodes under the pad (all of ``mesh.upper`` without a footprint)."""
    contacts: ContactSet = field(init=False, repr=False)
    """Every contact body's contacts (the floor's first, then the pad's)."""
    contact_dofs: np.ndarray = field(init=False, repr=False)
    """(n_contacts, 3) world x, y, z dofs of the contact nodes, in ``contacts`` order."""
    geometry: ElementGeometry = field(init=False, repr=False)
    pattern: SparsityPattern = field(init=False, repr=False)
    free_dofs: np.ndarray = field(init=False, repr=False)
    """(n_free,) dofs that are not prescribed (all but the upper-face dofs)."""
    upper_dofs: np.ndarray = field(init=False, repr=False)
    """(3 * n_upper,) prescribed dofs, node-major."""
    lower_dofs: np.ndarray = field(init=False, repr=False)
    """(n_lower, 3) world x, y, z dofs of the contact nodes."""
    frame: np.ndarray = field(init=False, repr=False)
    """(3, 3) world -> local contact frame rotation."""
    lower_area: np.ndarray = field(init=False, repr=False)
    """(n_lower,) tributary area of each contact node, m^2."""
    upper_area: np.ndarray = field(init=False, repr=False)
    """(n_upper,) tributary area of each upper-face node, m^2 (centroid weights)."""
    nodal_volume: np.ndarray = field(init=False, repr=False)
    """(n_nodes,) consistent nodal volumes, m^3 (:func:`fe_contact.fem.loads.nodal_volumes`)."""
    body_force: np.ndarray | None = field(init=False, repr=False)
    """(n_dofs,) self-weight, N, or None when ``material.density == 0``."""
    diagonal: np.ndarray = field(init=False, repr=False)
    """(n_dofs,) CSR data positions of the stiffness's diagonal."""
    factor_structure: SupernodalStructure | None = field(init=False, repr=False)
    """Symbolic multifrontal Cholesky factorisation of the free-dof stiffness:
    nested dissection of the interior, the contact dofs last in ``lower_dofs``
    order (:mod:`fe_contact.linalg.cholesky`); None if the mesh is not a tensor grid
    (then SuperLU factorises and orders)."""

    def __post_init__(self):
        if not isinstance(self.mesh, BlockMesh):
            raise ValueError(f"mesh must be a BlockMesh, got {type(self.mesh).__name__}")
        if not isinstance(self.material, Material):
            raise ValueError(f"material must be a Material, got {type(self.material).__name__}")
        if not isinstance(self.friction, Friction):
            raise ValueError(f"friction must be a Friction, got {type(self.friction).__name__}")
        if not isinstance(self.gripper, Gripper):
            raise ValueError(f"gripper must be a Gripper, got {type(self.gripper).__name__}")
        if self.pad is not None and not isinstance(self.pad, Friction):
            raise ValueError(f"pad must be a Friction or None (bonded), got {type(self.pad).__name__}")
        if self.footprint is not None and not isinstance(self.footprint, Footprint):
            raise ValueError(f"footprint must be a Footprint or None, got {type(self.footprint).__name__}")
        if self.quadrature not in (2, 3):
            # one point per element leaves the hex8 hourglass modes without
            # stiffness: K_ff is singular and the flexibility matrix meaningless
            raise ValueError(
                f"quadrature must be 2 or 3 Gauss points per direction (1 leaves hourglass modes), "
                f"got {self.quadrature!r}"
            )
        mesh = self.mesh
        set_ = object.__setattr__
        set_(self, "element", resolve_element(self.element, self.material.poisson))
        set_(self, "geometry", element_geometry(mesh, self.quadrature, self.element,
                                                fbar_weight(self.element, self.material.poisson)))
        set_(self, "pattern", sparsity_pattern(mesh.elements, mesh.n_nodes))
        set_(self, "held_nodes", self._held_nodes())
        upper_dofs = (3 * self.held_nodes[:, None] + np.arange(3)).ravel()
        if not self.hold_upper or self.pad is not None:
            upper_dofs = upper_dofs[:0]
        mask = np.ones(mesh.n_dofs, dtype=bool)
        mask[upper_dofs] = False
        set_(self, "upper_dofs", upper_dofs)
        set_(self, "free_dofs", np.flatnonzero(mask))
        set_(self, "lower_dofs", 3 * mesh.lower[:, None] + np.arange(3))
        set_(self, "frame", local_frame(self.friction.angle))
        set_(self, "contacts", stack_bodies(self._bodies()))
        set_(self, "contact_dofs", 3 * self.contacts.nodes[:, None] + np.arange(3))
        set_(self, "lower_area", face_tributary_areas(mesh, mesh.lower))
        set_(self, "upper_area", face_tributary_areas(mesh, mesh.upper))
        set_(self, "nodal_volume", nodal_volumes(mesh.elements, self.geometry.dvol, mesh.n_nodes,
                                                 self.quadrature))
        rho = self.material.density
        set_(self, "body_force", body_force(self.nodal_volume, rho) if rho > 0 else None)
        set_(self, "diagonal", diagonal_positions(self.pattern.indptr, self.pattern.indices))
        parts = nested_dissection_parts(mesh)
        if parts is None:
            set_(self, "factor_structure", None)
        else:
            is_contact = np.zeros(mesh.n_dofs, dtype=bool)
            is_contact[self.contact_dofs] = True
            interior = mask & ~is_contact
            dof_parts = [(3 * nodes[:, None] + np.arange(3)).ravel() for nodes in parts]
            set_(self, "factor_structure", supernodal_structure(
                self.pattern.indptr, self.pattern.indices, self.free_dofs,
                [d[interior[d]] for d in dof_parts], self.contact_dofs.ravel(),
            ))

    def _held_nodes(self) -> np.ndarray:
        """The upper-face nodes under the pad's footprint (read-only)."""
        upper = self.mesh.upper
        if self.footprint is not None:
            xy = self.mesh.nodes[upper, :2]
            upper = upper[self.footprint.select(xy, xy.mean(axis=0), self.mesh.size[:2])]
            upper.setflags(write=False)
        return upper

    def _bodies(self) -> tuple[ContactBody, ...]:
        """The floor (plane z = 0, normal up) and, if frictional, the pad (the
        plane of the upper face, normal down, moving with the gripper)."""
        f = self.friction
        floor = ContactBody("floor", self.mesh.lower, self.frame, np.zeros(3), f.mu_x, f.mu_y)
        if self.pad is None:
            return (floor,)
        top = float(self.mesh.nodes[self.mesh.upper, 2].max())
        return floor, ContactBody("pad", self.held_nodes, horizontal_frame(False, self.pad.angle),
                                  np.array([0.0, 0.0, top]), self.pad.mu_x, self.pad.mu_y, moves_with_gripper=True)

    def released(self) -> "Model":
        """This model with the upper face free (``hold_upper=False``), built once."""
        cache = self.__dict__.get("_released")
        if cache is None:
            cache = self if not self.hold_upper else replace(self, hold_upper=False)
            object.__setattr__(self, "_released", cache)
        return cache

    @property
    def reuses_tangent(self) -> bool:
        """Modified Newton (``SolverOptions.reuse_tangent``), except with a
        frictional pad: a tangent kept from the start of a step fails the local
        contact solve there (measured on a rubber block, pad mu 60: no local
        method converges at the next step's first iteration), a fresh one per
        iteration converges in 6-12 (full Newton)."""
        return self.options.reuse_tangent and self.pad is None

    @property
    def weight(self) -> float:
        """Self-weight of the block ``rho g V``, N."""
        return self.material.density * GRAVITY * float(self.nodal_volume.sum())

    @property
    def shear_stiffness(self) -> float:
        """In-plane stiffness of the block under a shear of its upper face, ``G A / H``, N/m."""
        lx, ly, lz = self.mesh.size
        return self.material.lame_mu * lx * ly / lz

    @property
    def n_contacts(self) -> int:
        """Contact nodes of every body (the floor's, then the pad's)."""
        return int(self.contacts.nodes.size)

    @property
    def n_lower(self) -> int:
        """Contact nodes on the floor (the lower face's)."""
        return int(self.mesh.lower.size)

    @property
    def upper_centre(self) -> np.ndarray:
        """(3,) reference centre of the upper face, m."""
        return self.mesh.nodes[self.mesh.upper].mean(axis=0)


def build_model(
    size,
    divisions,
    young: float,
    poisson: float,
    mu_x: float,
    mu_y: float,
    angle: float = 0.0,
    quadrature: int = 3,
    options: SolverOptions | None = None,
) -> Model:
    """Convenience constructor of a :class:`Model` for a rectangular block.

    Parameters
    ----------
    size : (3,) float
        Block size ``(lx, ly, lz)``, m.  Lower face on z = 0, centred on the origin.
    divisions : (3,) int
        Elements ``(nx, ny, nz)``.
    young, poisson : float
        St Venant-Kirchhoff material, Pa and -.
    mu_x, mu_y, angle : float
        Friction coefficients and orthotropy angle (rad).
    """
    return Model(
        mesh=block_mesh(size, divisions),
        material=Material(young, poisson),
        friction=Friction(mu_x, mu_y, angle),
        quadrature=quadrature,
        options=options or SolverOptions(),
    )


class TangentCache:
    """A state's handle on its cached tangent (:class:`fe_contact.stepping.tangent.Tangent`).

    ``value`` is the tangent or None.  Each :class:`State` gets its own handle;
    the steps branched from the state read it and leave it alone, except a step
    told ``consume=True``, which calls :meth:`release` at a refresh so that one
    factorised tangent is alive instead of two.  The frozen state itself is
    never modified: the handle is the one mutable thing it holds.
    """

    __slots__ = ("value",)

    def __init__(self, value=None):
        self.value = value

    def release(self) -> None:
        """Drop the cached tangent (the state steps on without it, from a new one)."""
        self.value = None

    def __repr__(self) -> str:
        return f"TangentCache({'empty' if self.value is None else type(self.value).__name__})"


@dataclass(frozen=True)
class State:
    """Path-dependent solution after some load steps.

    Attributes
    ----------
    displacement : ndarray, shape (n_nodes, 3)
        Total nodal displacement from the reference configuration, m.
    reaction : ndarray, shape (n_contacts, 3)
        Contact force on the block at each contact node (``model.contacts``
        order: the lower face's, then a frictional pad's), its body's local
        frame ``(n, t_x, t_y)``, N.
    upper_translation : ndarray, shape (3,)
        Cumulative translation of the upper face, m.
    upper_rotation : float
        Cumulative rotation of the upper face about z, rad.
    slip_path : ndarray, shape (n_lower,)
        Accumulated slip path length of each contact node (sum of slip increment
        norms), m.
    step_index : int
        Number of load steps taken.
    plate : ndarray, shape (3,)
        Actual in-plane pose ``(x, y, theta)`` of the upper-face plate, m, m,
        rad: the commanded one for a rigid drive, behind it by the spring
        deflection for a compliant gripper (default: the commanded pose).
    tangent : TangentCache
        Handle on the factorised tangent and flexibility matrix of an earlier
        configuration, reused by the next step when
        ``SolverOptions.reuse_tangent`` (a cache: excluded from comparisons;
        ``None`` gives an empty one).
    """

    displacement: np.ndarray
    reaction: np.ndarray
    upper_translation: np.ndarray
    upper_rotation: float
    slip_path: np.ndarray
    step_index: int = 0
    tangent: TangentCache = field(default_factory=TangentCache, compare=False, repr=False)
    plate: np.ndarray | None = None

    def __post_init__(self):
        if self.plate is None:
            object.__setattr__(self, "plate", np.array([*np.asarray(self.upper_translation, float)[:2],
                                                        self.upper_rotation]))
        if self.tangent is None:
            object.__setattr__(self, "tangent", TangentCache())
        elif not isinstance(self.tangent, TangentCache):
            raise ValueError(f"tangent must be a TangentCache or None, got {type(self.tangent).__name__}")
        for name in ("displacement", "reaction", "upper_translation", "slip_path", "plate"):
            a = np.array(getattr(self, name), dtype=float)  # copy: never alias a caller's array
            a.setflags(write=False)
            object.__setattr__(self, name, a)


def initial_state(model: Model) -> State:
    """Undeformed block resting on the plane with zero contact forces."""
    n_lower = model.n_lower
    return State(
        displacement=np.zeros((model.mesh.n_nodes, 3)),
        reaction=np.zeros((model.n_contacts, 3)),
        upper_translation=np.zeros(3),
        upper_rotation=0.0,
        slip_path=np.zeros(n_lower),
        step_index=0,
    )
