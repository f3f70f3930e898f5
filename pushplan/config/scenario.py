"""Scenario files (TOML, SI units): the schema, its validation and its round trip.

A scenario reads::

    name = "paper_case3"                      # optional, defaults to the file stem
    description = "..."                       # optional
    [block]
    size = [0.02, 0.02, 0.01]                 # lx, ly, lz (m); lower face on z = 0, centred
    elements = [20, 20, 5]                    # nx, ny, nz
    quadrature = 3                            # Gauss points per direction (2 or 3)
    [material]
    young = 210e9                             # Pa
    poisson = 0.3
    [friction]
    mu_x = 0.3
    mu_y = 0.05
    angle_deg = 0.0                           # orthotropy axis t_x from world x
    [[load]]                                  # applied in order
    dz = -1e-4                                # upper-face translation increment (m)
    [[load]]
    distance = 0.32e-3                        # in-plane push length (m) ...
    direction_deg = 45.0                      # ... and direction (instead of dx, dy)
    dtheta_deg = 0.0                          # optional rotation about the vertical axis
    repeat = 4                                # optional, applies the entry 4 times
    [solver]                                  # optional, fe_contact.SolverOptions fields
    local_method = "uzawa"

Unknown keys and invalid values raise :class:`~pushplan.errors.InputError` naming the
key.  The tables ``[plan]``, ``[mujoco]`` and ``[sweep]`` belong to other commands
(``pushplan.config.plan``, ``.mujoco``, ``.sweep`` validate them) and are kept raw in
``Scenario.extra``.  ``parse_scenario(scenario.to_dict())`` gives ``scenario`` back.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh
from fe_contact.model import LOCAL_METHODS

from ..errors import InputError
from .commands import MAX_TURN_DEG, commands_to_list
from .files import read_toml
from .validate import Table, count, positive_number

EXTRA_TABLES = ("plan", "mujoco", "sweep")
MAX_STEPS = 100_000
"""Most load steps a scenario may expand to (``repeat`` included): a guard against typos."""
MAX_ELEMENTS = 1_000_000
"""Most hex8 elements of a block: far beyond what fits in memory (dense flexibility matrix)."""
TOP_KEYS = {"name", "description", "block", "material", "friction", "load", "solver", *EXTRA_TABLES}
LOAD_KEYS = {"dx", "dy", "dz", "distance", "direction_deg", "dtheta_deg", "repeat"}
SOLVER_KEYS = {f for f in SolverOptions.__dataclass_fields__}

ScenarioError = InputError  # the name earlier versions exported


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (SI units, angles in radians inside ``Command``)."""

    name: str
    size: tuple[float, float, float]
    elements: tuple[int, int, int]
    quadrature: int
    young: float
    poisson: float
    mu_x: float
    mu_y: float
    angle_deg: float
    commands: tuple[Command, ...]
    solver: SolverOptions = field(default_factory=SolverOptions)
    description: str = ""
    extra: dict = field(default_factory=dict)

    def model(self, elements=None, quadrature=None) -> Model:
        """The ``fe_contact`` model; ``elements`` / ``quadrature`` override the mesh.

        Raises
        ------
        InputError
            ``fe_contact`` rejects a value (its message names it).
        """
        try:
            return Model(
                mesh=block_mesh(self.size, elements or self.elements),
                material=Material(self.young, self.poisson),
                friction=Friction(self.mu_x, self.mu_y, math.radians(self.angle_deg)),
                quadrature=quadrature or self.quadrature,
                options=self.solver,
            )
        except ValueError as exc:  # fe_contact's own checks at its public boundary
            raise InputError(f"scenario {self.name}: {exc}") from None

    def to_dict(self) -> dict:
        """The scenario as TOML-/JSON-ready tables (SI units): what
        :func:`parse_scenario` reads back into an equal scenario."""
        solver = {k: v for k, v in asdict(self.solver).items() if v is not None}
        return {
            "name": self.name,
            "description": self.description,
            "block": {"size": list(self.size), "elements": list(self.elements), "quadrature": self.quadrature},
            "material": {"young": self.young, "poisson": self.poisson},
            "friction": {"mu_x": self.mu_x, "mu_y": self.mu_y, "angle_deg": self.angle_deg},
            "load": commands_to_list(self.commands),
            "solver": solver,
            **{k: v for k, v in self.extra.items()},
        }


def _load_entry(i: int, entry) -> list[Command]:
    t = Table(entry, f"load[{i}]", LOAD_KEYS)
    polar = "distance" in t or "direction_deg" in t
    if polar and ("dx" in t or "dy" in t):
        raise InputError(f"{t.name}: give either dx/dy or distance/direction_deg, not both")
    if polar:
        if "distance" not in t or "direction_deg" not in t:
            raise InputError(f"{t.name}: distance and direction_deg go together")
        d = t.number("distance", nonneg=True)
        a = math.radians(t.number("direction_deg"))
        dx, dy = d * math.cos(a), d * math.sin(a)
    else:
        dx, dy = t.number("dx", 0.0), t.number("dy", 0.0)
    dz = t.number("dz", 0.0)
    dtheta = math.radians(t.number("dtheta_deg", 0.0, lo=-MAX_TURN_DEG, hi=MAX_TURN_DEG))
    repeat = t.integer("repeat", 1, minimum=1, maximum=MAX_STEPS)
    return [Command(dx, dy, dz, dtheta)] * repeat


def _solver(table) -> SolverOptions:
    t = Table(table, "solver", SOLVER_KEYS)
    values = dict(t.data)
    if "local_method" in t:
        t.choice("local_method", LOCAL_METHODS)
    if "reuse_tangent" in t:
        t.boolean("reuse_tangent")
    for k in ("local_tol", "newton_tol", "refresh_ratio"):
        if k in t:
            t.number(k, positive=True, hi=1.0)
    for k in ("local_max_iter", "newton_max_iter"):
        if k in t:
            t.integer(k, minimum=1)
    return SolverOptions(**values)


def _commands(loads) -> tuple[Command, ...]:
    if not isinstance(loads, list):
        raise InputError(f"load must be an array of tables ([[load]]), got {loads!r}")
    commands = [c for i, e in enumerate(loads) for c in _load_entry(i, e)]
    if len(commands) > MAX_STEPS:
        raise InputError(f"load must expand to at most {MAX_STEPS} steps, got {len(commands)}")
    return tuple(commands)


def parse_scenario(data: dict, name: str = "scenario") -> Scenario:
    """Validate a scenario given as a dict (the parsed TOML, or ``Scenario.to_dict()``)."""
    top = Table(data, "", TOP_KEYS)
    if "block" not in top:
        raise InputError("missing table [block]")
    if "material" not in top:
        raise InputError("missing table [material]")
    if "friction" not in top:
        raise InputError("missing table [friction]")
    block = top.table("block", {"size", "elements", "quadrature"}, required={"size", "elements"})
    elements = block.triple("elements", count)
    if math.prod(elements) > MAX_ELEMENTS:
        raise InputError(f"block.elements must give at most {MAX_ELEMENTS} elements, got {list(elements)}")
    quadrature = block.integer("quadrature", 3, minimum=1)
    if quadrature not in (2, 3):
        raise InputError(f"block.quadrature must be 2 or 3 (1 leaves hourglass modes), got {quadrature}")
    material = top.table("material", {"young", "poisson"}, required={"young", "poisson"})
    friction = top.table("friction", {"mu_x", "mu_y", "angle_deg"}, required={"mu_x", "mu_y"})
    return Scenario(
        name=top.string("name", name),
        description=top.string("description", ""),
        size=block.triple("size", positive_number),
        elements=elements,
        quadrature=quadrature,
        young=material.number("young", positive=True),
        poisson=material.number("poisson", lo=-1.0, hi=0.5),
        mu_x=friction.number("mu_x", nonneg=True),
        mu_y=friction.number("mu_y", nonneg=True),
        angle_deg=friction.number("angle_deg", 0.0),
        commands=_commands(data.get("load", [])),
        solver=_solver(data.get("solver", {})),
        extra={k: data[k] for k in EXTRA_TABLES if k in data},
    )


def load_scenario(path) -> Scenario:
    """Read and validate a TOML scenario file.

    Raises
    ------
    InputError
        Missing or unreadable file, malformed TOML, unknown key or bad value.
    """
    return parse_scenario(read_toml(path), name=Path(path).stem)


__all__ = ["EXTRA_TABLES", "MAX_ELEMENTS", "MAX_STEPS", "Scenario", "ScenarioError", "load_scenario",
           "parse_scenario"]
