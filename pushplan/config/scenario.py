"""Scenario files (TOML, SI units): the schema, its validation and its round trip.

A scenario reads::

    name = "paper_case3"                      # optional, defaults to the file stem
    description = "..."                       # optional
    [block]
    size = [0.02, 0.02, 0.01]                 # lx, ly, lz (m); lower face on z = 0, centred
    elements = [20, 20, 5]                    # nx, ny, nz
    quadrature = 3                            # Gauss points per direction (2 or 3)
    element = "auto"                          # optional: "hex8", "fbar" (does not lock as nu -> 0.5) or
                                              # "auto" (hex8 to nu 0.45, fbar from 0.48, blended); docs/materials.md
    [material]
    young = 210e9                             # Pa
    poisson = 0.3
    density = 0.0                             # optional, kg/m^3: self-weight (gravity 9.81 m/s^2 along -z)
    model = "stvk"                            # optional: "stvk" (the paper's), "neo_hookean", "hyperfoam"
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
    [gripper]                                 # optional: a compliant gripper (omitted: rigid drive)
    stiffness_xy = 4e4                        # N/m, > 0 (inf: rigid); with stiffness_yaw
    stiffness_yaw = 5.0                       # N m/rad, > 0 (inf: rigid)
    friction = "bonded"                       # the pad on the upper face: "bonded" (default, the paper's
                                              # displacement control), mu (isotropic, >= 0), or a table
                                              # {mu_x = .., mu_y = .., angle_deg = ..}: a rigid frictional
                                              # contact body (rigid or compliant gripper, lift release with
                                              # weight)
    pad_shape = "rectangle"                   # optional: the pad's footprint, "rectangle" or "disc"
    pad_size = [0.01, 0.01]                   # rectangle sides along x, y (m) (omitted: the whole face)
    pad_radius = 0.005                        # disc radius (m), instead of pad_size
    pad_offset = [0.0, 0.0]                   # pad centre from the upper face's centre (m)
    [release]                                 # optional: let go after the last load step
    mode = "lift"                             # the gripper rises until the pad carries no load ("open"
                                              # was removed: its rest pose depended on a pad stiffness)
    steps = 16                                # increments (>= 1; default 16, a frictional pad's 6)
    height = 0.0                              # the gripper rises to this height (m, >= 0) ...
    away = [0.0, 0.0]                         # ... retreating (dx, dy) m along with the rise
                                              # (a frictional pad: `steps` load steps of its load to 0;
                                              # error_tol was removed by issue 39, exit 2)

Unknown keys and invalid values raise :class:`~pushplan.errors.InputError` naming the
key.  The tables ``[plan]``, ``[mujoco]`` and ``[sweep]`` belong to other commands
(``pushplan.config.plan``, ``.mujoco``, ``.sweep`` validate them) and are kept raw in
``Scenario.extra``.  ``parse_scenario(scenario.to_dict())`` gives ``scenario`` back.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

from fe_contact import (AUTO_HEX8_POISSON, ELEMENTS, ERROR_TOL_REMOVED, FOOTPRINT_SHAPES, LAWS, LOCAL_METHODS, MU_MAX,
                        BlockMesh, Command, Footprint, Friction, Gripper, Material, Model, Release, SolverOptions,
                        block_mesh)

from ..errors import InputError, InputWarning
from ..limits import (MAX_ACCELERATION, MAX_ELEMENTS, MAX_ELEMENTS_PER_AXIS, MAX_GRIPPER_STIFFNESS, MAX_LENGTH,
                      MAX_LOCAL_ITER, MAX_NEWTON_ITER, MAX_STEPS, MIN_TOLERANCE)
from .commands import MAX_TURN_DEG, commands_to_list
from .files import read_toml
from .validate import Table, integer, number, positive_number

EXTRA_TABLES = ("plan", "mujoco", "sweep")
PLAUSIBLE = {"material.young": (1e4, 1e12, "Pa"), "block.size": (1e-4, 10.0, "m")}
"""Ranges outside which a value is valid but probably in the wrong unit: moduli from soft
foams (~10 kPa) to diamond (~1 TPa); blocks from 0.1 mm to 10 m."""
TOP_KEYS = {"name", "description", "block", "material", "friction", "load", "solver", "gripper", "release",
            *EXTRA_TABLES}
RELEASE_MODES = ("lift",)
DEFAULT_RELEASE_STEPS = 16
"""A bonded pad's lift increments when ``[release]`` omits ``steps``."""
DEFAULT_PAD_LOAD_STEPS = 6
"""A frictional pad's load steps when ``[release]`` omits ``steps``: the one count at which issue 39's two bounds
hold together (the release at most as many Newton iterations as its pushes, ``release_cost_6.json``; the rest within
0.5 % of the lag of 4 x the steps, ``release_refinement.json``: docs/release.md)."""
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
    density: float = 0.0
    gripper: Gripper | None = None
    release: Release | None = None
    pad: Friction | None = None
    """The gripper pad's friction (None: bonded)."""
    material_model: str = "stvk"
    element: str = "auto"
    footprint: Footprint | None = None
    """The pad's footprint on the upper face (None: the whole face)."""

    def model(self, elements=None, quadrature=None, what: str | None = None) -> Model:
        """The ``fe_contact`` model; ``elements`` / ``quadrature`` override the mesh
        (``what`` names the override in messages).  Every model of every command is built
        here, after the memory budget (:func:`~pushplan.config.budget.check_memory`).

        Every value was checked where it was parsed (:func:`parse_scenario`, the
        plan and the command line for the overrides): a ``ValueError`` from
        ``fe_contact`` here is a bug and keeps its traceback.

        Raises
        ------
        InputError
            The mesh's estimated memory exceeds the available memory.
        """
        from .budget import check_memory

        check_memory(elements or self.elements, quadrature or self.quadrature,
                     what=what or ("block.elements" if elements is None else "the mesh"))
        return Model(
            mesh=self.mesh(elements),
            material=Material(self.young, self.poisson, self.density, self.material_model),
            friction=Friction(self.mu_x, self.mu_y, math.radians(self.angle_deg)),
            quadrature=quadrature or self.quadrature,
            options=self.solver,
            gripper=self.gripper or Gripper(),
            pad=self.pad,
            element=self.element,
            footprint=self.footprint,
        )

    def mesh(self, elements=None) -> BlockMesh:
        """The block's mesh (of :meth:`model`; ``elements`` overrides the divisions), without
        the model's element geometry, sparsity and factorisation structure (a recording
        needs only the mesh)."""
        return block_mesh(self.size, elements or self.elements)

    def to_dict(self) -> dict:
        """The scenario as TOML-/JSON-ready tables (SI units): what
        :func:`parse_scenario` reads back into an equal scenario."""
        solver = {k: v for k, v in asdict(self.solver).items() if v is not None}
        material = {"young": self.young, "poisson": self.poisson}
        optional = {}  # tables and keys written only when set, so older files read the same
        if self.density:
            material["density"] = self.density
        if self.material_model != "stvk":
            material["model"] = self.material_model
        block = {"size": list(self.size), "elements": list(self.elements), "quadrature": self.quadrature}
        if self.element != "auto":
            block["element"] = self.element
        if self.gripper is not None:
            optional["gripper"] = {"stiffness_xy": self.gripper.stiffness_xy,
                                   "stiffness_yaw": self.gripper.stiffness_yaw}
        if self.pad is not None:
            optional.setdefault("gripper", {})["friction"] = pad_friction_dict(self.pad)
        if self.footprint is not None:
            optional.setdefault("gripper", {}).update(footprint_dict(self.footprint))
        if self.release is not None:
            optional["release"] = {"mode": self.release.mode, "steps": self.release.steps}
            if self.release.height:
                optional["release"]["height"] = self.release.height
            if any(self.release.away):
                optional["release"]["away"] = list(self.release.away)
        return {
            "name": self.name,
            "description": self.description,
            "block": block,
            "material": material,
            "friction": {"mu_x": self.mu_x, "mu_y": self.mu_y, "angle_deg": self.angle_deg},
            "load": commands_to_list(self.commands),
            "solver": solver,
            **optional,
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
    for k in ("local_tol", "newton_tol", "path_tol"):
        if k in t and t.number(k, positive=True, hi=1.0) < MIN_TOLERANCE:
            raise InputError(f"solver.{k} must be >= {MIN_TOLERANCE} (below double rounding it cannot be "
                             f"reached), got {t.data[k]!r}")
    if "refresh_ratio" in t:
        t.number("refresh_ratio", positive=True, hi=1.0)
    for k, most in (("local_max_iter", MAX_LOCAL_ITER), ("newton_max_iter", MAX_NEWTON_ITER)):
        if k in t:
            t.integer(k, minimum=1, maximum=most)
    if "acceleration" in t:
        t.integer("acceleration", minimum=0, maximum=MAX_ACCELERATION)
    if "pad_regularisation" in t:
        t.number("pad_regularisation", positive=True)
    return SolverOptions(**values)  # every field checked above: a ValueError here is a bug


def _stiffness(t: Table, k: str) -> float:
    value = t.data[k]
    if isinstance(value, float) and value == math.inf:
        return value  # a rigid drive, written as inf
    return t.number(k, positive=True, maximum=MAX_GRIPPER_STIFFNESS)


def _gripper(top: Table) -> tuple[Gripper | None, Friction | None]:
    if "gripper" not in top:
        return None, None
    t = top.table("gripper", {"stiffness_xy", "stiffness_yaw", "friction", *FOOTPRINT_KEYS})
    pad = _pad_friction(t) if "friction" in t else None
    if "stiffness_xy" not in t and "stiffness_yaw" not in t:
        return None, pad
    for k in ("stiffness_xy", "stiffness_yaw"):
        if k not in t:
            raise InputError(f"gripper.{k} is missing (stiffness_xy and stiffness_yaw go together)")
    xy, yaw = _stiffness(t, "stiffness_xy"), _stiffness(t, "stiffness_yaw")
    if math.isinf(xy) != math.isinf(yaw):
        raise InputError("gripper.stiffness_yaw must be inf with gripper.stiffness_xy = inf, and finite with it "
                         f"finite (a gripper is rigid or compliant), got {xy} and {yaw}")
    return Gripper(xy, yaw), pad


def _pad_friction(t: Table) -> Friction | None:
    """``gripper.friction``: "bonded" (None), a number (isotropic) or a table {mu_x, mu_y, angle_deg}."""
    value = t.data["friction"]
    if isinstance(value, str):
        if value != "bonded":
            raise InputError(f'gripper.friction must be "bonded", a number >= 0 or a table '
                             f"{{mu_x, mu_y, angle_deg}}, got {value!r}")
        return None
    if isinstance(value, dict):
        f = t.table("friction", {"mu_x", "mu_y", "angle_deg"}, required={"mu_x", "mu_y"})
        return Friction(_mu(f, "mu_x"), _mu(f, "mu_y"),
                        math.radians(f.number("angle_deg", 0.0)))
    mu = _mu(t, "friction")
    return Friction(mu, mu)


def _mu(t: Table, k: str) -> float:
    """A friction coefficient: from 0 to fe_contact's ``MU_MAX`` (beyond it the cone's
    scaling overflows and a step could not be trusted)."""
    return t.number(k, nonneg=True, maximum=MU_MAX)


FOOTPRINT_KEYS = ("pad_shape", "pad_size", "pad_radius", "pad_offset")


def _footprint(top: Table, size, elements) -> Footprint | None:
    """``gripper.pad_*``: the pad's footprint, checked against the upper face of the
    ``size`` (m) / ``elements`` block (inside it, a node under it); None: the whole face."""
    if "gripper" not in top:
        return None
    t = top.table("gripper", {"stiffness_xy", "stiffness_yaw", "friction", *FOOTPRINT_KEYS})
    if not any(k in t.data for k in FOOTPRINT_KEYS):
        return None
    shape = t.choice("pad_shape", FOOTPRINT_SHAPES, "rectangle")
    wanted, other = ("pad_radius", "pad_size") if shape == "disc" else ("pad_size", "pad_radius")
    if other in t.data:
        raise InputError(f"gripper.pad_shape = {shape!r} takes gripper.{wanted} (not {other}), got keys "
                         f"{sorted(k for k in t.data if k in FOOTPRINT_KEYS)}")
    if wanted not in t.data:
        given = "" if "pad_shape" in t.data else " (the default pad_shape)"
        raise InputError(f"gripper.{wanted} is missing: a pad footprint needs its size, pad_size = [a_x, a_y] (m) "
                         f"for pad_shape = \"rectangle\"{given} or pad_radius (m) for pad_shape = \"disc\"; "
                         "omit every pad_* key for the whole face")
    if shape == "disc":
        side = 2 * t.number("pad_radius", positive=True, maximum=MAX_LENGTH)
        sides = (side, side)
    else:
        sides = _pair(t, "pad_size", None, positive=True)
    offset = _pair(t, "pad_offset", [0.0, 0.0], minimum=-MAX_LENGTH, maximum=MAX_LENGTH)
    footprint = Footprint(shape, sides, offset)
    xy = block_mesh(size, (elements[0], elements[1], 1)).nodes[:, :2]
    try:
        footprint.select(xy, xy.mean(axis=0), size[:2])
    except ValueError as e:
        key, _, why = str(e).partition(": ")
        key = {"offset": "pad_offset", "size": wanted}[key]
        raise InputError(f"gripper.{key} = {t.data.get(key, [0.0, 0.0])!r}: {why}") from None
    return footprint


def _pair(t: Table, k: str, default, **bounds) -> tuple[float, float]:
    value = t.data.get(k, default)
    if not isinstance(value, list) or len(value) != 2:
        raise InputError(f"{t.key(k)} must be [x, y] in m, got {value!r}")
    return tuple(number(f"{t.key(k)}[{i}]", v, **bounds) for i, v in enumerate(value))


def footprint_dict(footprint: Footprint) -> dict:
    """The pad's footprint as written in files (``gripper.pad_*`` keys, m)."""
    size = {"pad_radius": footprint.size[0] / 2} if footprint.shape == "disc" else {"pad_size": list(footprint.size)}
    return {"pad_shape": footprint.shape, **size, "pad_offset": list(footprint.offset)}


def pad_friction_dict(pad: Friction | None):
    """The gripper pad's friction as written in files: "bonded" or {mu_x, mu_y, angle_deg}."""
    if pad is None:
        return "bonded"
    return {"mu_x": pad.mu_x, "mu_y": pad.mu_y, "angle_deg": math.degrees(pad.angle)}


def _release(top: Table, density: float, commands: tuple[Command, ...], pad: Friction | None) -> Release | None:
    if "release" not in top:
        return None
    if isinstance(top.data["release"], dict) and "error_tol" in top.data["release"]:  # removed: not an allowed key
        raise InputError(f"release.{ERROR_TOL_REMOVED}")
    t = top.table("release", {"mode", "steps", "height", "away"}, required={"mode"})
    if t.data.get("mode") == "open":
        raise InputError('release.mode = "open" was removed: its rest pose depended on an assumed pad stiffness '
                         'and schedule; use mode = "lift" with gripper.friction = mu (the pad as a frictional contact)')
    mode = t.choice("mode", RELEASE_MODES)
    if pad is not None and density <= 0:
        raise InputError("release with a frictional pad (gripper.friction) needs a block with weight "
                         "(material.density > 0): nothing holds a weightless block once the pad's load is zero")
    depth = sum(c.dz for c in commands)
    if depth >= 0:
        raise InputError(f"release.mode = {mode!r} needs a press before it: the loads' dz must sum to < 0 m, "
                         f"got {depth:g}")
    height = t.number("height", 0.0, nonneg=True, maximum=MAX_LENGTH)
    away = t.data.get("away", [0.0, 0.0])
    if not isinstance(away, list) or len(away) != 2:
        raise InputError(f"release.away must be [dx, dy] in m, got {away!r}")
    away = tuple(number(f"release.away[{i}]", v, minimum=-MAX_LENGTH, maximum=MAX_LENGTH) for i, v in enumerate(away))
    default = DEFAULT_RELEASE_STEPS if pad is None else DEFAULT_PAD_LOAD_STEPS
    return Release(mode, t.integer("steps", default, minimum=1, maximum=MAX_STEPS), height=height, away=away)


def _commands(loads) -> tuple[Command, ...]:
    if not isinstance(loads, list):
        raise InputError(f"load must be an array of tables ([[load]]), got {loads!r}")
    commands = [c for i, e in enumerate(loads) for c in _load_entry(i, e)]
    if len(commands) > MAX_STEPS:
        raise InputError(f"load must expand to at most {MAX_STEPS} steps, got {len(commands)}")
    return tuple(commands)


def _warn_implausible(key: str, values) -> None:
    low, high, unit = PLAUSIBLE[key]
    for v in values:
        if not low <= v <= high:
            warnings.warn(InputWarning(f"{key} = {v:g} {unit} is outside {low:g}-{high:g} {unit}, the range of "
                                       f"real blocks: is it in {unit}?"), stacklevel=3)
            return


def _axis_count(key: str, value) -> int:
    """A :func:`~pushplan.config.validate.triple` check: elements along one axis."""
    return integer(key, value, 1, MAX_ELEMENTS_PER_AXIS)


def parse_scenario(data: dict, name: str = "scenario") -> Scenario:
    """Validate a scenario given as a dict (the parsed TOML, or ``Scenario.to_dict()``)."""
    top = Table(data, "", TOP_KEYS)
    if "block" not in top:
        raise InputError("missing table [block]")
    if "material" not in top:
        raise InputError("missing table [material]")
    if "friction" not in top:
        raise InputError("missing table [friction]")
    block = top.table("block", {"size", "elements", "quadrature", "element"}, required={"size", "elements"})
    elements = block.triple("elements", _axis_count)
    if math.prod(elements) > MAX_ELEMENTS:
        raise InputError(f"block.elements must give at most {MAX_ELEMENTS} elements, got {list(elements)}")
    quadrature = block.integer("quadrature", 3, minimum=1, maximum=3)
    if quadrature not in (2, 3):
        raise InputError(f"block.quadrature must be 2 or 3 (1 leaves hourglass modes), got {quadrature}")
    material = top.table("material", {"young", "poisson", "density", "model"}, required={"young", "poisson"})
    density = material.number("density", 0.0, nonneg=True)
    friction = top.table("friction", {"mu_x", "mu_y", "angle_deg"}, required={"mu_x", "mu_y"})
    commands = _commands(data.get("load", []))
    gripper, pad = _gripper(top)
    scenario = Scenario(
        name=top.string("name", name),
        description=top.string("description", ""),
        size=block.triple("size", positive_number),
        elements=elements,
        quadrature=quadrature,
        young=material.number("young", positive=True),
        poisson=material.number("poisson", lo=-1.0, hi=0.5),
        mu_x=_mu(friction, "mu_x"),
        mu_y=_mu(friction, "mu_y"),
        angle_deg=friction.number("angle_deg", 0.0),
        commands=commands,
        solver=_solver(data.get("solver", {})),
        extra={k: data[k] for k in EXTRA_TABLES if k in data},
        density=density,
        gripper=gripper,
        pad=pad,
        release=_release(top, density, commands, pad),
        material_model=material.choice("model", LAWS, "stvk"),
        element=block.choice("element", ("auto", *ELEMENTS), "auto"),
        footprint=_footprint(top, block.triple("size", positive_number), elements),
    )
    _warn_implausible("material.young", [scenario.young])
    _warn_implausible("block.size", scenario.size)
    if scenario.element == "hex8" and scenario.poisson > AUTO_HEX8_POISSON:
        warnings.warn(InputWarning(
            f"block.element = \"hex8\" with material.poisson = {scenario.poisson:g} locks: too stiff, the more so "
            f"as poisson -> 0.5 (press force 9.5x the converged one at 0.499 on 4x4x2); use \"fbar\" or \"auto\""),
            stacklevel=2)
    return scenario


def load_scenario(path) -> Scenario:
    """Read and validate a TOML scenario file.

    Raises
    ------
    InputError
        Missing or unreadable file, malformed TOML, unknown key or bad value.
    """
    return parse_scenario(read_toml(path), name=Path(path).stem)


__all__ = ["EXTRA_TABLES", "MAX_ELEMENTS", "MAX_STEPS", "Scenario", "ScenarioError", "load_scenario",
           "pad_friction_dict", "parse_scenario"]
