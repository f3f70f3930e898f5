"""What a load step reports: its :class:`Status`, per-iteration logs and the
:class:`StepReport` of measurements (SI units)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from .command import Command


class Status(enum.Enum):
    """Outcome of a load step."""

    CONVERGED = "converged"
    NEWTON_NOT_CONVERGED = "newton_not_converged"
    CONTACT_NOT_CONVERGED = "contact_not_converged"
    ELEMENT_INVERTED = "element_inverted"
    NOT_FINITE = "not_finite"
    TANGENT_SINGULAR = "tangent_singular"  # K_ff singular or too ill-conditioned for W
    MATERIAL_UNSTABLE = "material_unstable"  # the law's tangent lost positive definiteness (StVK in compression)


class NodeStatus(enum.IntEnum):
    """Contact status of a lower-face node at the end of a step."""

    STICK = 0
    SLIP = 1
    SEPARATED = 2


@dataclass(frozen=True)
class IterLog:
    """One Newton iteration: relative out-of-balance force before the update,
    local-solver iterations, final local residual, the local method that
    solved the contact problem (the chosen one, or its fallback), and whether
    the iterate was an Anderson mix (:mod:`fe_contact.stepping.acceleration`:
    its contact forces need not satisfy the law, its residual is no convergence test)."""

    newton_residual: float
    contact_iterations: int
    contact_residual: float
    contact_method: str = ""
    mixed: bool = False


@dataclass(frozen=True)
class StepReport:
    """Everything measured in one load step (SI units; arrays per lower-face node
    are ordered as ``mesh.lower``).

    When ``status`` is not ``CONVERGED`` the returned state is the input state and
    the per-node fields describe the last iterate (for diagnosis only).
    """

    status: Status
    message: str
    step_index: int
    command: Command
    displacement: np.ndarray  # (n_nodes, 3) m
    reaction_local: np.ndarray  # (n_lower, 3) N, (n, t_x, t_y)
    reaction_world: np.ndarray  # (n_lower, 3) N, (x, y, z)
    pressure: np.ndarray  # (n_lower,) Pa, r_n / tributary area
    slip_increment: np.ndarray  # (n_lower, 2) m, world x, y
    slip: np.ndarray  # (n_lower,) m, norm of total tangential displacement (the paper's "slip")
    slip_path: np.ndarray  # (n_lower,) m, accumulated path length
    gap: np.ndarray  # (n_lower,) m, normal gap at the end of the step
    node_status: np.ndarray  # (n_lower,) NodeStatus values
    upper_centroid: np.ndarray  # (3,) cumulative displacement, m
    lower_centroid: np.ndarray  # (3,) cumulative displacement, m
    lower_yaw: float  # rad, best-fit planar rotation of the lower face
    twist: float  # rad, signed angle from the upper to the lower in-plane centroid displacement
    lag: np.ndarray  # (2,) m, upper minus lower in-plane centroid displacement
    normal_force: float  # N, total normal contact force (> 0 in compression)
    tangential_force: np.ndarray  # (2,) N, world x, y total friction force on the block
    upper_force: np.ndarray  # (3,) N, total force the upper-face drive applies on the block
    equilibrium_error: float  # |sum contact + upper forces| / force scale of the step
    dissipation: float  # J, frictional dissipation of the step (>= 0)
    newton_iterations: int
    contact_iterations: int  # total local-solver iterations over the step
    newton_residual: float
    contact_residual: float
    min_det_f: float
    wall_time: float  # s
    iterations: tuple[IterLog, ...] = ()
    tangent_updates: int = 0  # flexibility matrices computed in the step
    timings: dict = field(default_factory=dict)  # s per phase: assembly, tangent, local, solve

    strain_energy: float = 0.0  # J, stored elastic energy at the end of the step
    gripper_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """(3,) force and moment the gripper springs apply on the plate (N, N, N m);
    the rigid drive's upper-face reaction for a rigid gripper."""
    plate: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) plate pose (x, y, theta), m, m, rad
    weight: float = 0.0  # N, the block's self-weight
    regularisation_force: float = 0.0  # N, norm of the regularising spring forces (frictional pad)
    pad_reaction: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(n_upper, 3) N, a frictional pad's contact force on each upper-face node, the pad's frame (n, t_x, t_y)
    (empty for a bonded pad)."""
    pad_force: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(n_held, 3) N, world (x, y, z): the force the pad applies on each node under it (``Model.held_nodes``
    order), a bonded pad's drive reaction or a frictional pad's contact force; zeros once a bonded pad let go;
    its sum is ``upper_force``."""

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def contact_methods(self) -> tuple[str, ...]:
        """The local methods that solved the step's contact problems, in order of first use."""
        return tuple(dict.fromkeys(log.contact_method for log in self.iterations))

    @property
    def n_stick(self) -> int:
        return int(np.count_nonzero(self.node_status == NodeStatus.STICK))

    @property
    def n_slip(self) -> int:
        return int(np.count_nonzero(self.node_status == NodeStatus.SLIP))

    @property
    def n_separated(self) -> int:
        return int(np.count_nonzero(self.node_status == NodeStatus.SEPARATED))
