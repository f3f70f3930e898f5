"""TOML scenario files: parsing, validation and conversion to ``fe_contact`` objects.

A scenario (SI units) reads::

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

Unknown keys and invalid values raise :class:`ScenarioError` naming the key.
Other tables (``[plan]``, ``[mujoco]``) belong to other commands and are kept raw
in ``Scenario.extra`` for them to validate.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from fe_contact import Command, Friction, Material, Model, SolverOptions, block_mesh
from fe_contact.model import LOCAL_METHODS

EXTRA_TABLES = ("plan", "mujoco", "sweep")
MAX_STEPS = 100_000
"""Most load steps a scenario may expand to (``repeat`` included): a guard against typos."""
MAX_ELEMENTS = 1_000_000
"""Most hex8 elements of a block: far beyond what fits in memory (dense flexibility matrix)."""


class ScenarioError(ValueError):
    """Invalid scenario file or value; the message names the key."""


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
        """The ``fe_contact`` model; ``elements`` / ``quadrature`` override the mesh."""
        return Model(
            mesh=block_mesh(self.size, elements or self.elements),
            material=Material(self.young, self.poisson),
            friction=Friction(self.mu_x, self.mu_y, math.radians(self.angle_deg)),
            quadrature=quadrature or self.quadrature,
            options=self.solver,
        )

    def to_dict(self) -> dict:
        """Resolved parameters, JSON-ready (SI units)."""
        return {
            "name": self.name,
            "description": self.description,
            "block": {"size": list(self.size), "elements": list(self.elements), "quadrature": self.quadrature},
            "material": {"young": self.young, "poisson": self.poisson},
            "friction": {"mu_x": self.mu_x, "mu_y": self.mu_y, "angle_deg": self.angle_deg},
            "load": [
                {"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": math.degrees(c.dtheta)} for c in self.commands
            ],
            "solver": asdict(self.solver),
        }


def _number(key: str, value: Any, *, positive=False, nonneg=False, lo=None, hi=None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{key} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ScenarioError(f"{key} must be finite, got {value!r}")
    if positive and v <= 0:
        raise ScenarioError(f"{key} must be > 0, got {value!r}")
    if nonneg and v < 0:
        raise ScenarioError(f"{key} must be >= 0, got {value!r}")
    if lo is not None and not v > lo:
        raise ScenarioError(f"{key} must be > {lo}, got {value!r}")
    if hi is not None and not v < hi:
        raise ScenarioError(f"{key} must be < {hi}, got {value!r}")
    return v


def _integer(key: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(f"{key} must be an integer, got {value!r}")
    if value < minimum:
        raise ScenarioError(f"{key} must be >= {minimum}, got {value!r}")
    return value


def _table(data: dict, key: str, allowed: set[str], required: bool = True) -> dict:
    if key not in data:
        if required:
            raise ScenarioError(f"missing table [{key}]")
        return {}
    table = data[key]
    if not isinstance(table, dict):
        raise ScenarioError(f"{key} must be a table, got {table!r}")
    for k in table:
        if k not in allowed:
            raise ScenarioError(f"unknown key {key}.{k} (allowed: {', '.join(sorted(allowed))})")
    return table


def _triple(key: str, value: Any, kind) -> list:
    if not isinstance(value, list) or len(value) != 3:
        raise ScenarioError(f"{key} must be a list of 3 values, got {value!r}")
    return [kind(f"{key}[{i}]", v) for i, v in enumerate(value)]


def _load_entry(i: int, entry: Any) -> list[Command]:
    key = f"load[{i}]"
    if not isinstance(entry, dict):
        raise ScenarioError(f"{key} must be a table, got {entry!r}")
    allowed = {"dx", "dy", "dz", "distance", "direction_deg", "dtheta_deg", "repeat"}
    for k in entry:
        if k not in allowed:
            raise ScenarioError(f"unknown key {key}.{k} (allowed: {', '.join(sorted(allowed))})")
    polar = "distance" in entry or "direction_deg" in entry
    if polar and ("dx" in entry or "dy" in entry):
        raise ScenarioError(f"{key}: give either dx/dy or distance/direction_deg, not both")
    if polar:
        if "distance" not in entry or "direction_deg" not in entry:
            raise ScenarioError(f"{key}: distance and direction_deg go together")
        d = _number(f"{key}.distance", entry["distance"], nonneg=True)
        a = math.radians(_number(f"{key}.direction_deg", entry["direction_deg"]))
        dx, dy = d * math.cos(a), d * math.sin(a)
    else:
        dx = _number(f"{key}.dx", entry.get("dx", 0.0))
        dy = _number(f"{key}.dy", entry.get("dy", 0.0))
    dz = _number(f"{key}.dz", entry.get("dz", 0.0))
    dtheta = math.radians(_number(f"{key}.dtheta_deg", entry.get("dtheta_deg", 0.0)))
    repeat = _integer(f"{key}.repeat", entry.get("repeat", 1), 1)
    if repeat > MAX_STEPS:
        raise ScenarioError(f"{key}.repeat must be <= {MAX_STEPS}, got {repeat}")
    return [Command(dx, dy, dz, dtheta)] * repeat


def parse_scenario(data: dict, name: str = "scenario") -> Scenario:
    """Validate a scenario given as a dict (the parsed TOML)."""
    top = {"name", "description", "block", "material", "friction", "load", "solver", *EXTRA_TABLES}
    for k in data:
        if k not in top:
            raise ScenarioError(f"unknown key {k} (allowed: {', '.join(sorted(top))})")
    for k in ("name", "description"):
        if k in data and not isinstance(data[k], str):
            raise ScenarioError(f"{k} must be a string, got {data[k]!r}")
    block = _table(data, "block", {"size", "elements", "quadrature"})
    for k in ("size", "elements"):
        if k not in block:
            raise ScenarioError(f"missing key block.{k}")
    size = _triple("block.size", block["size"], lambda k, v: _number(k, v, positive=True))
    elements = _triple("block.elements", block["elements"], lambda k, v: _integer(k, v, 1))
    if math.prod(elements) > MAX_ELEMENTS:
        raise ScenarioError(f"block.elements must give at most {MAX_ELEMENTS} elements, got {elements}")
    quadrature = _integer("block.quadrature", block.get("quadrature", 3), 1)
    if quadrature not in (2, 3):
        raise ScenarioError(f"block.quadrature must be 2 or 3 (1 leaves hourglass modes), got {quadrature}")
    mat = _table(data, "material", {"young", "poisson"})
    for k in ("young", "poisson"):
        if k not in mat:
            raise ScenarioError(f"missing key material.{k}")
    young = _number("material.young", mat["young"], positive=True)
    poisson = _number("material.poisson", mat["poisson"], lo=-1.0, hi=0.5)
    fr = _table(data, "friction", {"mu_x", "mu_y", "angle_deg"})
    for k in ("mu_x", "mu_y"):
        if k not in fr:
            raise ScenarioError(f"missing key friction.{k}")
    mu_x = _number("friction.mu_x", fr["mu_x"], nonneg=True)
    mu_y = _number("friction.mu_y", fr["mu_y"], nonneg=True)
    angle = _number("friction.angle_deg", fr.get("angle_deg", 0.0))
    loads = data.get("load", [])
    if not isinstance(loads, list):
        raise ScenarioError(f"load must be an array of tables ([[load]]), got {loads!r}")
    commands = [c for i, e in enumerate(loads) for c in _load_entry(i, e)]
    if len(commands) > MAX_STEPS:
        raise ScenarioError(f"load must expand to at most {MAX_STEPS} steps, got {len(commands)}")
    solver_keys = {"local_method", "local_tol", "local_max_iter", "newton_tol", "newton_max_iter", "reuse_tangent",
                   "refresh_ratio"}
    sv = _table(data, "solver", solver_keys, required=False)
    if "local_method" in sv and sv["local_method"] not in LOCAL_METHODS:
        raise ScenarioError(f"solver.local_method must be one of {LOCAL_METHODS}, got {sv['local_method']!r}")
    for k in ("local_tol", "newton_tol", "refresh_ratio"):
        if k in sv:
            _number(f"solver.{k}", sv[k], positive=True, hi=1.0)
    for k in ("local_max_iter", "newton_max_iter"):
        if k in sv:
            _integer(f"solver.{k}", sv[k], 1)
    if "reuse_tangent" in sv and not isinstance(sv["reuse_tangent"], bool):
        raise ScenarioError(f"solver.reuse_tangent must be true or false, got {sv['reuse_tangent']!r}")
    return Scenario(
        name=data.get("name", name),
        description=str(data.get("description", "")),
        size=tuple(size),
        elements=tuple(elements),
        quadrature=quadrature,
        young=young,
        poisson=poisson,
        mu_x=mu_x,
        mu_y=mu_y,
        angle_deg=angle,
        commands=tuple(commands),
        solver=SolverOptions(**sv),
        extra={k: data[k] for k in EXTRA_TABLES if k in data},
    )


def read_toml(path, what: str = "scenario") -> dict:
    """Parse a TOML file into a dict; ``what`` names the file kind in messages.

    Raises
    ------
    ScenarioError
        Missing or unreadable file, malformed TOML.
    """
    path = Path(path)
    try:
        text = path.read_bytes()
    except FileNotFoundError:
        raise ScenarioError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise ScenarioError(f"cannot read {what} file {path}: {exc.strerror}") from None
    try:
        return tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"malformed TOML in {path}: {exc}") from None


def load_scenario(path) -> Scenario:
    """Read and validate a TOML scenario file.

    Raises
    ------
    ScenarioError
        Missing or unreadable file, malformed TOML, unknown key or bad value.
    """
    return parse_scenario(read_toml(path), name=Path(path).stem)
