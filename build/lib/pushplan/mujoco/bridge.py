"""MuJoCo bridge: MJCF scene import, co-simulation coupler, rigid / flex comparison
and plan export.  MuJoCo is imported lazily here, never in ``fe_contact``.

MuJoCo facts this module is built on (MuJoCo 4.0, checked with ``data.contact``):

* Anisotropic friction exists only on a geom-geom ``<pair condim="3"
  friction="f1 f2 ...">`` with ``cone="elliptic"``; ``f1`` acts along the contact
  tangent ``t1``, ``f2`` along ``t2``.  For a box on a horizontal plane the frame is
  built from the normal alone: ``t1 = world +y``, ``t2 = world -x`` whatever the yaw
  of either body.  :func:`scene_from_mjcf` reads the frame of the actual contacts
  and maps it to our ``(mu_x, mu_y, angle)`` in the block's own frame.
* Flex contacts are isotropic; 3D flex elasticity needs ``integrator="discrete"``
  and cannot hang from a mocap body, so the flex comparison pins the flex to a
  dynamic pad welded to a mocap gripper.
* ``MjSpec.add_equality`` starts with the *connect* data layout; a weld needs its
  data set explicitly (anchor 0, relpose "from qpos0" sentinel, torquescale 1).

Frames: the FE model (``fe_contact``) has the block's lower face on ``z = 0``
centred on its origin, axes along the block's edges.  The MuJoCo block's reference
pose (at ``qpos0``) fixes that frame in the world: origin at the lower-face centre
``MjcfScene.lower_centre``, rotated by ``MjcfScene.yaw`` about world z.

``export_plan`` writes ``.npz`` files with

``time`` (K+1,) s; ``mocap_pos`` (K+1, 3) m and ``mocap_quat`` (K+1, 4) (w, x, y, z)
of the gripper mocap body; ``upper_centre`` (K+1, 3) m and ``upper_yaw`` (K+1,) rad of
the block's upper-face centre carried by the gripper; ``gripper`` (name).  Knot 0 is
the reference pose; knot k is reached at the end of command k.  An ``.xml`` export
is an MJCF file with one ``<key>`` per knot (``mpos``/``mquat`` of every mocap
body), for ``<include file="..."/>`` in the scene.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from fe_contact import Command, Model, SolverOptions, State, StepReport, initial_state, step

from ..errors import InputError
from ..outputs.atomic import atomic_write_bytes, atomic_write_json, atomic_write_npz
from ..config.scenario import Scenario, load_scenario

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

NUMERIC_YOUNG = "pushplan_young"
NUMERIC_POISSON = "pushplan_poisson"
DEFAULT_ELEMENTS = (8, 8, 4)
DEFAULT_QUADRATURE = 2
VERTICAL_TOL = 1e-9
"""|1 - |R_zz|| above which a floor normal or block axis is not vertical."""
FRAME_TOL = 1e-9
"""Spread of the contact frames / frictions of one pair above which they differ."""
WELD_TIMECONST_STEPS = 2.0
"""Weld ``solref`` time constant in timesteps (MuJoCo's stable minimum is 2)."""
FLEX_RADIUS = 0.01
"""Flex vertex radius relative to the smallest grid spacing."""
FORCE_RUN_MAX_PERIODS = 50
"""Force-driven rigid box: time limit per command, in control periods."""
FLEX_DAMPING = 1e-9
"""Flex Rayleigh damping, s: negligible, but it marks the flex as having passive forces
(MuJoCo 4.0 otherwise warns, and writes MUJOCO_LOG.TXT, that an elastic flex under the
discrete integrator has none)."""
ZERO_MOTION = 1e-12
"""In-plane displacement (relative to the block size) below which a direction is undefined."""

MUJOCO_KEYS = {
    "scene", "block", "floor", "gripper", "control_period", "settle_time",
    "flex_points", "flex_mu", "force_factor",
}


def _mujoco():
    import mujoco

    return mujoco


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quat_z(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def _yaw_of(R: np.ndarray) -> float:
    return float(math.atan2(R[1, 0], R[0, 0]))


def _wrap(angle: float) -> float:
    return float((angle + math.pi) % (2 * math.pi) - math.pi)


def signed_angle(a: np.ndarray, b: np.ndarray, scale: float) -> float:
    """Signed in-plane angle from ``a`` to ``b`` (rad, counter-clockwise); zero when
    either is shorter than ``ZERO_MOTION * scale`` (no direction)."""
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    if np.linalg.norm(a) <= ZERO_MOTION * scale or np.linalg.norm(b) <= ZERO_MOTION * scale:
        return 0.0
    return float(math.atan2(a[0] * b[1] - a[1] * b[0], a @ b))


# --------------------------------------------------------------------------- import


@dataclass(frozen=True)
class MjcfScene:
    """An FE scenario read from an MJCF scene, and where the block sits in it.

    Attributes
    ----------
    scenario : Scenario
        Block size, friction and (when present) material from the MJCF; the rest
        from the base scenario or defaults (see ``not_from_mjcf``).
    source : str
        MJCF file path, or ``""`` when imported from an ``MjModel``.
    block_body, block_geom, floor_geom : str
        Names (or ``"#id"`` when unnamed).
    pair : str or None
        The ``<pair>`` giving the friction, or None for a dynamic (isotropic) contact.
    lower_centre : ndarray, shape (3,)
        World position of the block's lower-face centre at ``qpos0``, m (FE origin).
    yaw : float
        Block yaw at ``qpos0``, rad (FE frame rotation about world z).
    body_pos, body_quat : ndarray, shape (3,), (4,)
        World pose of the block body at ``qpos0`` (quaternion w, x, y, z).
    block_mass : float
        Mass of the block body's subtree, kg.
    from_mjcf, not_from_mjcf : dict
        Scenario field -> where its value came from.
    notes : tuple of str
        What MuJoCo models differently or the FE model ignores.
    """

    scenario: Scenario
    source: str
    block_body: str
    block_geom: str
    floor_geom: str
    pair: str | None
    lower_centre: np.ndarray
    yaw: float
    body_pos: np.ndarray
    body_quat: np.ndarray
    block_mass: float
    from_mjcf: dict = field(default_factory=dict)
    not_from_mjcf: dict = field(default_factory=dict)
    notes: tuple = ()

    @property
    def upper_centre(self) -> np.ndarray:
        """(3,) world position of the upper-face centre at ``qpos0``, m."""
        return self.lower_centre + np.array([0.0, 0.0, self.scenario.size[2]])

    def to_world(self, v: np.ndarray) -> np.ndarray:
        """Rotate FE-frame vectors ``(..., 3)`` into the world."""
        return np.asarray(v, float) @ _rz(self.yaw).T

    def to_fe(self, v: np.ndarray) -> np.ndarray:
        """Rotate world vectors ``(..., 3)`` into the FE frame."""
        return np.asarray(v, float) @ _rz(self.yaw)

    def summary(self) -> dict:
        """JSON-ready description of the import."""
        s = self.scenario
        return {
            "source": self.source, "block_body": self.block_body, "block_geom": self.block_geom,
            "floor_geom": self.floor_geom, "pair": self.pair, "size": list(s.size),
            "mu_x": s.mu_x, "mu_y": s.mu_y, "angle_deg": s.angle_deg, "young": s.young,
            "poisson": s.poisson, "lower_centre": self.lower_centre, "yaw_deg": math.degrees(self.yaw),
            "block_mass": self.block_mass, "from_mjcf": self.from_mjcf,
            "not_from_mjcf": self.not_from_mjcf, "notes": list(self.notes),
        }


def _name(m, objtype, i: int) -> str:
    name = _mujoco().mj_id2name(m, objtype, i)
    return name if name else f"#{i}"


def _find(m, objtype, name: str, what: str) -> int:
    if name.startswith("#") and name[1:].isdigit():  # unnamed object, as _name writes it
        return int(name[1:])
    i = _mujoco().mj_name2id(m, objtype, name)
    if i < 0:
        raise InputError(f"{what} {name!r} not found in the MJCF model")
    return i


def _block_ids(m, block: str) -> tuple[int, int]:
    mj = _mujoco()
    gid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_GEOM, block)
    if gid >= 0:
        return int(m.geom_bodyid[gid]), gid
    bid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, block)
    if bid < 0:
        raise InputError(f"block {block!r} is neither a body nor a geom of the MJCF model")
    geoms = np.flatnonzero(m.geom_bodyid == bid)
    boxes = geoms[m.geom_type[geoms] == mj.mjtGeom.mjGEOM_BOX]
    if boxes.size != 1:
        raise InputError(f"block body {block!r} must hold exactly one box geom, it holds {boxes.size}")
    return bid, int(boxes[0])


def _load_model(source) -> tuple[Any, str]:
    mj = _mujoco()
    if isinstance(source, mj.MjModel):
        return source, ""
    path = Path(source)
    if not path.is_file():
        raise InputError(f"MJCF file not found: {path}")
    try:
        return mj.MjModel.from_xml_path(str(path)), str(path)
    except ValueError as exc:
        raise InputError(f"cannot load MJCF {path}: {exc}") from None


def _material(m, base: Scenario | None, from_mjcf: dict, not_from: dict) -> tuple[float, float]:
    out = {}
    for key, numeric in (("young", NUMERIC_YOUNG), ("poisson", NUMERIC_POISSON)):
        try:
            data = np.asarray(m.numeric(numeric).data, float)
        except KeyError:
            data = None
        if data is not None:
            if data.size != 1 or not np.isfinite(data[0]):
                raise InputError(f"<numeric name={numeric!r}> must hold one finite number, got {data.tolist()}")
            out[key] = float(data[0])
            from_mjcf[f"material.{key}"] = f"<numeric name='{numeric}'>"
        elif base is not None:
            out[key] = getattr(base, key)
            not_from[f"material.{key}"] = "scenario"
        else:
            raise InputError(
                f"material.{key}: the MJCF has no <numeric name={numeric!r}> and no scenario was given"
            )
    if out["young"] <= 0:
        raise InputError(f"{NUMERIC_YOUNG} must be > 0, got {out['young']}")
    if not -1.0 < out["poisson"] < 0.5:
        raise InputError(f"{NUMERIC_POISSON} must be in (-1, 0.5), got {out['poisson']}")
    return out["young"], out["poisson"]


def _friction(m, d, bgeom: int, fgeom: int, yaw: float, notes: list) -> tuple[float, float, float, str | None]:
    """(mu_x, mu_y, angle_deg, pair) from the block-floor contacts at qpos0."""
    mj = _mujoco()
    geoms = np.sort(np.asarray(d.contact.geom[: d.ncon]).reshape(-1, 2), axis=1)
    mine = np.flatnonzero((geoms == sorted((bgeom, fgeom))).all(axis=1))
    if mine.size == 0:
        raise InputError(
            f"block geom {_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} does not touch floor "
            f"{_name(m, mj.mjtObj.mjOBJ_GEOM, fgeom)!r} at qpos0; rest the block on the floor"
        )
    frames = np.asarray(d.contact.frame[: d.ncon])[mine].reshape(-1, 3, 3)
    fric = np.asarray(d.contact.friction[: d.ncon])[mine]
    dims = np.asarray(d.contact.dim[: d.ncon])[mine]
    if np.ptp(frames, axis=0).max() > FRAME_TOL or np.ptp(fric, axis=0).max() > FRAME_TOL or np.ptp(dims) > 0:
        raise InputError("the block-floor contacts disagree on frame, friction or condim")
    frame, f, dim = frames[0], fric[0], int(dims[0])
    if abs(abs(frame[0, 2]) - 1.0) > VERTICAL_TOL:
        raise InputError(f"block-floor contact normal {frame[0].tolist()} is not vertical; the FE plane is z = 0")
    pairs = [i for i in range(m.npair) if sorted((m.pair_geom1[i], m.pair_geom2[i])) == sorted((bgeom, fgeom))]
    pair = (_name(m, mj.mjtObj.mjOBJ_PAIR, pairs[0])) if pairs else None
    if pair is None:
        notes.append("no <pair> for block and floor: friction is MuJoCo's isotropic mix of the geom frictions")
    if m.opt.cone != mj.mjtCone.mjCONE_ELLIPTIC:
        notes.append("opt.cone is pyramidal: MuJoCo approximates the elliptic cone of the FE model")
    if dim == 1:
        notes.append("condim = 1: frictionless contact")
        return 0.0, 0.0, 0.0, pair
    if dim > 3:
        notes.append(f"condim = {dim}: torsional/rolling friction {f[2:].tolist()} has no FE counterpart (ignored)")
    # tangents in the FE frame; t_x is the one nearer the block's x edge
    t1 = frame[1] @ _rz(yaw)
    t2 = frame[2] @ _rz(yaw)
    if abs(t1[0]) >= abs(t2[0]):
        mu_x, mu_y, tx = float(f[0]), float(f[1]), t1
    else:
        mu_x, mu_y, tx = float(f[1]), float(f[0]), t2
    angle = math.degrees(math.atan2(tx[1], tx[0]))
    angle = (angle + 90.0) % 180.0 - 90.0  # an ellipse axis is defined modulo 180 deg
    return mu_x, mu_y, 0.0 if abs(angle) < 1e-9 else angle, pair


def scene_from_mjcf(source, block: str = "block", floor: str = "floor", base: Scenario | None = None) -> MjcfScene:
    """Build our scenario from an MJCF scene.

    Parameters
    ----------
    source : path or mujoco.MjModel
        MJCF file or compiled model.
    block : str
        Block body (holding one box geom) or box geom name.
    floor : str
        Plane geom name; its normal must be world +z.
    base : Scenario, optional
        Supplies what the MJCF cannot (mesh, quadrature, solver, load steps) and the
        material when the MJCF has no ``<custom><numeric name="pushplan_young">`` /
        ``"pushplan_poisson"``.  MJCF values replace the base's size and friction
        (differences are listed in ``notes``).

    Returns
    -------
    MjcfScene

    Raises
    ------
    ValueError
        Missing file or name, block not a vertical box resting on the floor, floor
        not a horizontal plane, missing or bad material.
    """
    mj = _mujoco()
    m, path = _load_model(source)
    bbody, bgeom = _block_ids(m, block)
    fgeom = _find(m, mj.mjtObj.mjOBJ_GEOM, floor, "floor geom")
    if m.geom_type[bgeom] != mj.mjtGeom.mjGEOM_BOX:
        raise InputError(f"block geom {_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} must be a box")
    if m.geom_type[fgeom] != mj.mjtGeom.mjGEOM_PLANE:
        raise InputError(f"floor geom {floor!r} must be a plane")
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    Rf = d.geom_xmat[fgeom].reshape(3, 3)
    if abs(Rf[2, 2] - 1.0) > VERTICAL_TOL:
        raise InputError(f"floor {floor!r} normal {Rf[:, 2].tolist()} is not world +z")
    Rb = d.geom_xmat[bgeom].reshape(3, 3)
    if abs(abs(Rb[2, 2]) - 1.0) > VERTICAL_TOL:
        raise InputError(f"block geom z axis {Rb[:, 2].tolist()} is not vertical; stand the box upright")
    size = tuple(float(2 * v) for v in m.geom_size[bgeom])
    yaw = _yaw_of(Rb)
    lower = d.geom_xpos[bgeom] - np.array([0.0, 0.0, size[2] / 2])
    notes: list[str] = []
    mu_x, mu_y, angle, pair = _friction(m, d, bgeom, fgeom, yaw, notes)
    from_mjcf = {
        "block.size": f"box geom {_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} (2 x size)",
        "friction.mu_x": "contact friction along the tangent nearer the block x edge",
        "friction.mu_y": "contact friction along the other tangent",
        "friction.angle_deg": "MuJoCo contact frame (world-fixed) seen from the block frame",
    }
    not_from: dict[str, str] = {}
    young, poisson = _material(m, base, from_mjcf, not_from)
    src = "scenario" if base is not None else "default"
    for key in ("block.elements", "block.quadrature", "solver", "load"):
        not_from[key] = src
    if base is not None:
        for key, ours, theirs in (
            ("block.size", size, tuple(base.size)), ("friction.mu_x", mu_x, base.mu_x),
            ("friction.mu_y", mu_y, base.mu_y), ("friction.angle_deg", angle, base.angle_deg),
        ):
            if not np.allclose(ours, theirs, rtol=1e-9, atol=1e-12):
                notes.append(f"scenario {key} {theirs} replaced by the MJCF value {ours}")
    if abs(d.geom_xpos[bgeom][2] - size[2] / 2 - d.geom_xpos[fgeom][2]) > 1e-9 * size[2]:
        notes.append("block lower face is not exactly on the floor at qpos0; the FE model starts in contact")
    notes.append("MuJoCo contact softness (solref, solimp, margin) has no FE counterpart")
    scenario = Scenario(
        name=base.name if base is not None else (Path(path).stem if path else "mjcf"),
        size=size,
        elements=tuple(base.elements) if base is not None else DEFAULT_ELEMENTS,
        quadrature=base.quadrature if base is not None else DEFAULT_QUADRATURE,
        young=young, poisson=poisson, mu_x=mu_x, mu_y=mu_y, angle_deg=angle,
        commands=tuple(base.commands) if base is not None else (),
        solver=base.solver if base is not None else SolverOptions(local_method="newton"),
        description=base.description if base is not None else f"imported from {path or 'an MjModel'}",
        extra=dict(base.extra) if base is not None else {},
    )
    return MjcfScene(
        scenario=scenario, source=path,
        block_body=_name(m, mj.mjtObj.mjOBJ_BODY, bbody), block_geom=_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom),
        floor_geom=_name(m, mj.mjtObj.mjOBJ_GEOM, fgeom), pair=pair,
        lower_centre=np.array(lower), yaw=yaw, body_pos=d.xpos[bbody].copy(), body_quat=d.xquat[bbody].copy(),
        block_mass=float(m.body_subtreemass[bbody]), from_mjcf=from_mjcf, not_from_mjcf=not_from,
        notes=tuple(notes),
    )


# ---------------------------------------------------------------- settings / files


@dataclass(frozen=True)
class BridgeSettings:
    """The ``[mujoco]`` table of a scenario (SI units)."""

    scene: str = ""
    block: str = "block"
    floor: str = "floor"
    gripper: str = "gripper"
    control_period: float = 0.05
    settle_time: float = 0.05
    flex_points: tuple[int, int, int] = (3, 3, 2)
    flex_mu: float | None = None
    force_factor: float = 1.2

    def __post_init__(self):
        for key in ("control_period", "force_factor"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise InputError(f"mujoco.{key} must be a number > 0, got {v!r}")
        v = self.settle_time
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"mujoco.settle_time must be a number >= 0, got {v!r}")
        if self.force_factor <= 1.0:
            raise InputError(f"mujoco.force_factor must be > 1 (above the sliding threshold), got {self.force_factor}")
        pts = self.flex_points
        if (not isinstance(pts, (list, tuple)) or len(pts) != 3
                or any(isinstance(p, bool) or not isinstance(p, int) or p < 2 for p in pts)):
            raise InputError(f"mujoco.flex_points must be 3 integers >= 2, got {pts!r}")
        object.__setattr__(self, "flex_points", tuple(pts))
        if self.flex_mu is not None and (
            isinstance(self.flex_mu, bool) or not isinstance(self.flex_mu, (int, float)) or self.flex_mu < 0
        ):
            raise InputError(f"mujoco.flex_mu must be a number >= 0, got {self.flex_mu!r}")
        for key in ("scene", "block", "floor", "gripper"):
            if not isinstance(getattr(self, key), str):
                raise InputError(f"mujoco.{key} must be a string, got {getattr(self, key)!r}")


def bridge_settings(table: dict) -> BridgeSettings:
    """Validate a ``[mujoco]`` table (unknown keys raise ValueError naming them)."""
    if not isinstance(table, dict):
        raise InputError(f"mujoco must be a table, got {table!r}")
    for k in table:
        if k not in MUJOCO_KEYS:
            raise InputError(f"unknown key mujoco.{k} (allowed: {', '.join(sorted(MUJOCO_KEYS))})")
    return BridgeSettings(**table)


def open_scene(path, block: str | None = None, floor: str | None = None) -> tuple[MjcfScene, BridgeSettings]:
    """Open a scenario TOML with a ``[mujoco]`` table, or a bare MJCF file.

    A TOML's ``mujoco.scene`` is relative to the TOML; a bare MJCF gets default
    mesh and solver settings and no load steps.  ``block`` / ``floor`` override
    the settings' names.
    """
    path = Path(path)
    if path.suffix.lower() == ".toml":
        base = load_scenario(path)
        if "mujoco" not in base.extra:
            raise InputError(f"{path} has no [mujoco] table naming the MJCF scene")
        settings = bridge_settings(base.extra["mujoco"])
        if not settings.scene:
            raise InputError(f"{path}: missing key mujoco.scene")
        xml = path.parent / settings.scene
    elif path.suffix.lower() in (".xml", ".mjcf"):
        base, settings, xml = None, BridgeSettings(scene=str(path)), path
    else:
        raise InputError(f"scene must be a .toml scenario or an .xml MJCF file, got {path}")
    scene = scene_from_mjcf(xml, block=block or settings.block, floor=floor or settings.floor, base=base)
    return scene, settings


# ---------------------------------------------------------------- gripper trajectory


@dataclass(frozen=True)
class GripperTrajectory:
    """Gripper knots, one per command boundary (see the module docstring).

    Shapes: ``time`` (K+1,), ``mocap_pos`` (K+1, 3), ``mocap_quat`` (K+1, 4),
    ``upper_centre`` (K+1, 3), ``upper_yaw`` (K+1,)."""

    time: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    upper_centre: np.ndarray
    upper_yaw: np.ndarray
    gripper: str

    def at(self, k: int, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Mocap (pos, quat) a fraction ``s`` in [0, 1] of the way from knot k to k+1."""
        pos = (1 - s) * self.mocap_pos[k] + s * self.mocap_pos[k + 1]
        dyaw = (1 - s) * self.upper_yaw[k] + s * self.upper_yaw[k + 1] - self.upper_yaw[0]
        return pos, _quat_mul(_quat_z(dyaw), self.mocap_quat[0])


def _gripper_frame(m, d, name: str) -> tuple[str, int, np.ndarray, np.ndarray]:
    """('body' | 'site', id, world pos, world rotation) of a body or site."""
    mj = _mujoco()
    bid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, name)
    if bid >= 0:
        return "body", bid, d.xpos[bid].copy(), d.xmat[bid].reshape(3, 3).copy()
    sid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_SITE, name)
    if sid >= 0:
        return "site", sid, d.site_xpos[sid].copy(), d.site_xmat[sid].reshape(3, 3).copy()
    raise InputError(f"gripper {name!r} is neither a body nor a site of the MJCF model")


def gripper_trajectory(scene: MjcfScene, mj_model, commands: Sequence[Command], gripper: str = "gripper",
                       control_period: float = 0.05) -> GripperTrajectory:
    """Mocap knots that carry the block's upper face through ``commands``.

    The upper-face centre is rigidly attached to the gripper (yaw only; tilt is not
    representable by the FE command): each command moves it by ``(dx, dy, dz)``
    (FE frame, converted to world) and turns the gripper by ``dtheta``.

    Raises
    ------
    ValueError
        ``gripper`` is not a mocap body, bad ``control_period`` or command.
    """
    mj = _mujoco()
    if not (isinstance(control_period, (int, float)) and math.isfinite(control_period) and control_period > 0):
        raise InputError(f"control_period must be > 0 s, got {control_period!r}")
    bid = mj.mj_name2id(mj_model, mj.mjtObj.mjOBJ_BODY, gripper)
    if bid < 0 or mj_model.body_mocapid[bid] < 0:
        raise InputError(f"gripper {gripper!r} must be a mocap body to follow a command list")
    for i, c in enumerate(commands):
        if not isinstance(c, Command):
            raise InputError(f"commands[{i}] must be a fe_contact.Command, got {type(c).__name__}")
    p0 = np.array(mj_model.body_pos[bid], float)
    q0 = np.array(mj_model.body_quat[bid], float)
    R0 = np.zeros(9)
    mj.mju_quat2Mat(R0, q0)
    yaw0 = _yaw_of(R0.reshape(3, 3))
    offset = _rz(-yaw0) @ (scene.upper_centre - p0)
    steps = np.array([[c.dx, c.dy, c.dz] for c in commands], float).reshape(-1, 3)
    turns = np.array([c.dtheta for c in commands], float)
    centre = scene.upper_centre + np.vstack([np.zeros(3), np.cumsum(scene.to_world(steps), axis=0)])
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(turns)])
    pos = centre - np.einsum("kij,j->ki", np.stack([_rz(a) for a in yaw]), offset)
    quat = np.stack([_quat_mul(_quat_z(a - yaw0), q0) for a in yaw])
    times = control_period * np.arange(len(commands) + 1)
    return GripperTrajectory(times, pos, quat, centre, yaw, gripper)


def export_plan(path, scene: MjcfScene, commands: Sequence[Command], gripper: str = "gripper",
                control_period: float = 0.05) -> Path:
    """Write the gripper trajectory of a plan as ``.npz`` or MJCF ``<keyframe>`` ``.xml``.

    Raises
    ------
    ValueError
        Unknown suffix, or the scene source is not a file (for the mocap layout).
    """
    path = Path(path)
    if path.suffix.lower() not in (".npz", ".xml"):
        raise InputError(f"plan export must be .npz or .xml, got {path.name}")
    m, _ = _load_model(scene.source) if scene.source else (None, "")
    if m is None:
        raise InputError("export_plan needs a scene imported from an MJCF file")
    traj = gripper_trajectory(scene, m, commands, gripper, control_period)
    if path.suffix.lower() == ".npz":
        return atomic_write_npz(
            path, time=traj.time, mocap_pos=traj.mocap_pos, mocap_quat=traj.mocap_quat,
            upper_centre=traj.upper_centre, upper_yaw=traj.upper_yaw, gripper=np.array(gripper),
        )
    mj = _mujoco()
    mocap_bodies = np.flatnonzero(m.body_mocapid >= 0)
    order = mocap_bodies[np.argsort(m.body_mocapid[mocap_bodies])]
    mine = int(m.body_mocapid[mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, gripper)])
    fmt = lambda a: " ".join(f"{v:.17g}" for v in a.ravel())  # noqa: E731
    lines = [f'<mujoco model="{gripper}_plan">', "  <!-- pushplan gripper trajectory: include in the scene -->",
             "  <keyframe>"]
    for k in range(traj.time.size):
        mpos = np.array(m.body_pos[order], float)
        mquat = np.array(m.body_quat[order], float)
        mpos[mine], mquat[mine] = traj.mocap_pos[k], traj.mocap_quat[k]
        lines.append(f'    <key name="plan_{k:03d}" time="{traj.time[k]:.17g}" '
                     f'mpos="{fmt(mpos)}" mquat="{fmt(mquat)}"/>')
    lines += ["  </keyframe>", "</mujoco>", ""]
    return atomic_write_bytes(path, "\n".join(lines).encode())


# ---------------------------------------------------------------- co-simulation


class CoSimulation:
    """Couple the FE block into an ordinary MuJoCo stepping loop.

    Call :meth:`update` after every ``mj_step``.  At each control period it turns
    the gripper's displacement since the previous period into an upper-face
    :class:`fe_contact.Command`, steps the FE model and writes the block's
    resulting lower-face pose (centroid displacement and best-fit yaw) into the
    MuJoCo block (free joint ``qpos`` with zero ``qvel``, or mocap pose).  Between
    periods it re-writes that pose, so MuJoCo shows the FE prediction, not its own
    rigid dynamics.  A failed FE step keeps the last good state and pose; the next
    period retries with the accumulated gripper motion.

    At construction the block is put at its reference (``qpos0``) pose and the FE
    state is the undeformed block; the gripper's pose then fixes where the upper
    face is attached to it.

    Parameters
    ----------
    mj_model, mj_data : mujoco.MjModel, mujoco.MjData
    scene : MjcfScene
        Import of the same MJCF.
    gripper : str
        Body or site carrying the upper face (mocap or any other).
    control_period : float
        s of MuJoCo time between FE steps; the first is one period after construction.
    fe_model : fe_contact.Model, optional
        Defaults to ``scene.scenario.model()``; its block must have the MJCF size.
    """

    def __init__(self, mj_model, mj_data, scene: MjcfScene, gripper: str = "gripper",
                 control_period: float = 0.05, fe_model: Model | None = None):
        mj = _mujoco()
        if not (isinstance(control_period, (int, float)) and math.isfinite(control_period)
                and control_period >= mj_model.opt.timestep):
            raise InputError(
                f"control_period must be >= the MuJoCo timestep {mj_model.opt.timestep}, got {control_period!r}")
        self.mj_model, self.mj_data, self.scene = mj_model, mj_data, scene
        self.model = fe_model or scene.scenario.model()
        extent = np.ptp(self.model.mesh.nodes, axis=0)
        if not np.allclose(extent, scene.scenario.size, rtol=1e-9):
            raise InputError(
                f"fe_model block size {extent.tolist()} differs from the MJCF box {list(scene.scenario.size)}")
        self.state: State = initial_state(self.model)
        self.reports: list[StepReport] = []
        self.control_period = float(control_period)
        self.step_wall: list[float] = []
        bid = _find(mj_model, mj.mjtObj.mjOBJ_BODY, scene.block_body, "block body")
        self._mocap = int(mj_model.body_mocapid[bid])
        if self._mocap < 0:
            jnt = int(mj_model.body_jntadr[bid])
            if mj_model.body_jntnum[bid] != 1 or mj_model.jnt_type[jnt] != mj.mjtJoint.mjJNT_FREE:
                raise InputError(f"block body {scene.block_body!r} must have one free joint or be a mocap body")
            self._qadr, self._vadr = int(mj_model.jnt_qposadr[jnt]), int(mj_model.jnt_dofadr[jnt])
        mj.mj_kinematics(mj_model, mj_data)
        self._gripper = gripper
        self._gkind, self._gid, pg, Rg = _gripper_frame(mj_model, mj_data, gripper)
        yaw_g = _yaw_of(Rg)
        self._offset = _rz(-yaw_g) @ (scene.upper_centre - pg)
        self._last = (scene.upper_centre.copy(), yaw_g)
        self._next = mj_data.time + self.control_period
        self.lower_displacement = np.zeros(3)  # FE frame, m
        self.lower_yaw = 0.0
        self._write_pose()
        mj.mj_forward(mj_model, mj_data)

    def drive_pose(self) -> tuple[np.ndarray, float]:
        """(world upper-face centre carried by the gripper (3,), gripper yaw) now."""
        d = self.mj_data
        if self._gkind == "body":
            p, R = d.xpos[self._gid], d.xmat[self._gid].reshape(3, 3)
        else:
            p, R = d.site_xpos[self._gid], d.site_xmat[self._gid].reshape(3, 3)
        yaw = _yaw_of(R)
        return p + _rz(yaw) @ self._offset, yaw

    def block_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World (pos (3,), quat (4,)) of the block body for the current FE lower-face pose."""
        s = self.scene
        R = _rz(self.lower_yaw)
        pos = s.lower_centre + s.to_world(self.lower_displacement) + R @ (s.body_pos - s.lower_centre)
        return pos, _quat_mul(_quat_z(self.lower_yaw), s.body_quat)

    def _write_pose(self) -> None:
        pos, quat = self.block_pose()
        d = self.mj_data
        if self._mocap >= 0:
            d.mocap_pos[self._mocap], d.mocap_quat[self._mocap] = pos, quat
        else:
            d.qpos[self._qadr:self._qadr + 3], d.qpos[self._qadr + 3:self._qadr + 7] = pos, quat
            d.qvel[self._vadr:self._vadr + 6] = 0.0

    def update(self) -> StepReport | None:
        """Call after each ``mj_step``: runs :meth:`control` when a period is due
        (returns its report), otherwise holds the block pose (returns None)."""
        if self.mj_data.time + 0.5 * self.mj_model.opt.timestep < self._next:
            self._write_pose()
            return None
        return self.control()

    def control(self) -> StepReport:
        """One control period now: gripper motion -> FE step -> block pose into MuJoCo."""
        mj = _mujoco()
        t0 = time.perf_counter()
        mj.mj_kinematics(self.mj_model, self.mj_data)
        centre, yaw = self.drive_pose()
        d = self.scene.to_fe(centre - self._last[0])
        cmd = Command(d[0], d[1], d[2], _wrap(yaw - self._last[1]))
        new_state, rep = step(self.model, self.state, cmd)
        self.reports.append(rep)
        if rep.converged:
            self.state, self._last = new_state, (centre, yaw)
            self.lower_displacement = np.array(rep.lower_centroid, float)
            self.lower_yaw = float(rep.lower_yaw)
        self._next += self.control_period
        self._write_pose()
        mj.mj_forward(self.mj_model, self.mj_data)
        self.step_wall.append(time.perf_counter() - t0)
        return rep


def _block_geom_pose(m, d, scene: MjcfScene) -> tuple[np.ndarray, np.ndarray, float]:
    """(lower-face centre, upper-face centre, yaw) of the MuJoCo block geom, world."""
    mj = _mujoco()
    gid = _find(m, mj.mjtObj.mjOBJ_GEOM, scene.block_geom, "block geom")
    R = d.geom_xmat[gid].reshape(3, 3)
    half = 0.5 * scene.scenario.size[2] * R[:, 2] * np.sign(R[2, 2])
    return d.geom_xpos[gid] - half, d.geom_xpos[gid] + half, _yaw_of(R)


def run_cosimulation(scene: MjcfScene, commands: Sequence[Command], gripper: str = "gripper",
                     control_period: float = 0.05, fe_model: Model | None = None, rrd_path=None) -> dict:
    """Headless co-simulation: the gripper mocap follows ``commands`` (one per
    control period, linear in between), the coupler steps the FE model.

    Returns a JSON-ready record (per-period command, FE lower-face pose, the pose
    MuJoCo shows, twist, wall times) with ``rate_periods_per_s``.  With
    ``rrd_path`` the run is also saved as a rerun recording.
    """
    mj = _mujoco()
    m, _ = _load_model(scene.source) if scene.source else (None, "")
    if m is None:
        raise InputError("run_cosimulation needs a scene imported from an MJCF file")
    traj = gripper_trajectory(scene, m, commands, gripper, control_period)
    n_sub = int(round(control_period / m.opt.timestep))
    if n_sub < 1 or abs(n_sub * m.opt.timestep - control_period) > 1e-9 * control_period:
        raise InputError(f"control_period {control_period} must be a multiple of the MuJoCo timestep {m.opt.timestep}")
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    coupler = CoSimulation(m, d, scene, gripper, control_period, fe_model)
    mocap = int(m.body_mocapid[mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, gripper)])
    periods, frames = [], []
    t0 = time.perf_counter()
    for k in range(len(commands)):
        rep = None
        for j in range(1, n_sub + 1):
            d.mocap_pos[mocap], d.mocap_quat[mocap] = traj.at(k, j / n_sub)
            mj.mj_step(m, d)
            rep = coupler.update() or rep
        if rep is None:  # cannot happen when control_period is a multiple of the timestep
            raise RuntimeError(f"no control step in period {k + 1}")
        low, up, yaw = _block_geom_pose(m, d, scene)
        c = rep.command
        periods.append({
            "period": k + 1, "time": float(d.time), "status": rep.status.value,
            "command": {"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": math.degrees(c.dtheta)},
            "fe_lower_centroid": rep.lower_centroid, "fe_lower_yaw_deg": math.degrees(rep.lower_yaw),
            "fe_twist_deg": math.degrees(rep.twist), "mujoco_lower_centre": low,
            "mujoco_yaw_deg": math.degrees(yaw), "fe_step_s": rep.wall_time, "control_wall_s": coupler.step_wall[-1],
        })
        frames.append((traj.upper_centre[k + 1], low, yaw))
        if not rep.converged:
            break
    wall = time.perf_counter() - t0
    record = {
        "scene": scene.summary(), "gripper": gripper, "control_period": control_period,
        "mujoco_steps_per_period": n_sub, "fe_elements": list(coupler.model.mesh.divisions),
        "fe_quadrature": coupler.model.quadrature,
        "status": "completed" if periods and periods[-1]["status"] == "converged" and len(periods) == len(commands)
        else "failed",
        "periods": periods, "wall_s": wall, "rate_periods_per_s": len(periods) / wall if wall > 0 else math.inf,
    }
    if rrd_path is not None:
        _save_rerun(Path(rrd_path), coupler.model, scene, coupler.reports, frames)
    return record


def _save_rerun(path: Path, model: Model, scene: MjcfScene, reports: list[StepReport], frames) -> None:
    """Rerun recording of the co-simulation: the FE steps through
    :class:`pushplan.recording.Recorder` (replayable), plus ``mujoco/gripper_centre``,
    ``mujoco/block_lower_centre`` (Points3D) and ``plots/mujoco_yaw_deg`` (Scalars),
    in the recorder's frame (the FE frame: lower face centred on the origin)."""
    import rerun as rr

    from ..outputs.recording import Recorder
    from ..run.summary import StepSummary

    with Recorder(path, f"cosim_{scene.scenario.name}", model.mesh, scenario=scene.scenario.to_dict()) as rec:
        for rep, (drive, low, yaw) in zip(reports, frames):
            rec.log_step(rep, StepSummary.from_report(rep))
            rec.stream.log("mujoco/gripper_centre", rr.Points3D([scene.to_fe(drive - scene.lower_centre)]))
            rec.stream.log("mujoco/block_lower_centre", rr.Points3D([scene.to_fe(low - scene.lower_centre)]))
            rec.stream.log("plots/mujoco_yaw_deg", rr.Scalars(math.degrees(yaw - scene.yaw)))


# ---------------------------------------------------------------- comparison


def _record(k: int, drive: np.ndarray, upper: np.ndarray, lower: np.ndarray, yaw: float, scale: float) -> dict:
    return {
        "step": k, "drive": drive, "upper": upper, "lower": lower, "lower_yaw_deg": math.degrees(yaw),
        "twist_deg": math.degrees(signed_angle(upper, lower, scale)),
        "deviation_deg": math.degrees(signed_angle(drive, lower, scale)),
    }


def _fe_run(scene: MjcfScene, commands, fe_model: Model) -> list[dict]:
    state = initial_state(fe_model)
    out, scale = [], max(scene.scenario.size)
    for k, c in enumerate(commands, start=1):
        state, rep = step(fe_model, state, c)
        if not rep.converged:
            raise RuntimeError(f"FE step {k} failed: {rep.message}")
        up, low = scene.to_world(rep.upper_centroid), scene.to_world(rep.lower_centroid)
        out.append(_record(k, up, up, low, rep.lower_yaw, scale))
    return out


def _weld_spec(scene: MjcfScene, gripper: str):
    mj = _mujoco()
    spec = mj.MjSpec.from_file(scene.source)
    eq = spec.add_equality()
    eq.name, eq.type, eq.objtype = "pushplan_weld", mj.mjtEq.mjEQ_WELD, mj.mjtObj.mjOBJ_BODY
    eq.name1, eq.name2 = gripper, scene.block_body
    data = np.zeros(len(eq.data))
    data[3:10] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # relpose sentinel: keep the qpos0 relative pose
    data[10] = 1.0  # torquescale
    eq.data = data
    eq.solref = [WELD_TIMECONST_STEPS * spec.option.timestep, 1.0]
    return spec.compile()


def _rigid_weld_run(scene, traj, n_move, n_settle) -> list[dict]:
    mj = _mujoco()
    m = _weld_spec(scene, traj.gripper)
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    mocap = int(m.body_mocapid[mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, traj.gripper)])
    low0, up0, yaw0 = _block_geom_pose(m, d, scene)
    out, scale = [], max(scene.scenario.size)
    for k in range(traj.time.size - 1):
        for j in range(1, n_move + n_settle + 1):
            d.mocap_pos[mocap], d.mocap_quat[mocap] = traj.at(k, min(j / n_move, 1.0))
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        low, up, yaw = _block_geom_pose(m, d, scene)
        out.append(_record(k + 1, traj.upper_centre[k + 1] - traj.upper_centre[0], up - up0, low - low0,
                           _wrap(yaw - yaw0), scale))
    return out


def _rigid_force_run(scene, commands, traj, n_move, n_settle, force_factor) -> list[dict]:
    """Rigid box pushed by a horizontal force at its centre of mass: per command, a
    constant force along the command direction, ``force_factor`` times the sliding
    threshold under the box's weight, until the box has travelled the command's
    in-plane length; then released and settled.  Vertical moves are not applied."""
    mj = _mujoco()
    m, _ = _load_model(scene.source)
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    bid = _find(m, mj.mjtObj.mjOBJ_BODY, scene.block_body, "block body")
    for _ in range(n_settle):
        mj.mj_step(m, d)
    low0, up0, yaw0 = _block_geom_pose(m, d, scene)
    s = scene.scenario
    weight = scene.block_mass * float(np.linalg.norm(m.opt.gravity))
    a = math.radians(s.angle_deg)
    out, scale = [], max(s.size)
    for k, c in enumerate(commands, start=1):
        length = math.hypot(c.dx, c.dy)
        if length > ZERO_MOTION * scale:
            u = np.array([c.dx, c.dy]) / length
            u_fr = np.array([math.cos(a) * u[0] + math.sin(a) * u[1], -math.sin(a) * u[0] + math.cos(a) * u[1]])
            mu = np.array([s.mu_x, s.mu_y])
            threshold = weight / np.linalg.norm(u_fr / mu) if np.all(mu > 0) else weight * float(np.min(mu))
            force = max(threshold, 1e-3 * weight) * force_factor * scene.to_world(np.array([u[0], u[1], 0.0]))
            start = _block_geom_pose(m, d, scene)[0]
            for _ in range(FORCE_RUN_MAX_PERIODS * n_move):
                d.xfrc_applied[bid, :3] = force
                mj.mj_step(m, d)
                if np.linalg.norm((d.xpos[bid] - start)[:2]) >= length:
                    break
            d.xfrc_applied[bid, :3] = 0.0
        for _ in range(n_settle):
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        low, up, yaw = _block_geom_pose(m, d, scene)
        drive = traj.upper_centre[k] - traj.upper_centre[0]
        out.append(_record(k, drive, up - up0, low - low0, _wrap(yaw - yaw0), scale))
    return out


def flex_mjcf(scene: MjcfScene, points: tuple[int, int, int], mu: float, timestep: float,
              gravity: np.ndarray) -> str:
    """MJCF of the isotropic flex comparison: a 3D grid flexcomp of the block's size
    and material, top layer pinned to a pad welded to a mocap ``gripper`` at the
    upper-face centre, on a plane with isotropic friction ``mu``."""
    s = scene.scenario
    spacing = [s.size[i] / (points[i] - 1) for i in range(3)]
    radius = FLEX_RADIUS * min(spacing)
    centre = scene.lower_centre + np.array([0.0, 0.0, s.size[2] / 2 + radius])
    up = scene.upper_centre + np.array([0.0, 0.0, radius])
    q = _quat_z(scene.yaw)
    v = lambda a: " ".join(f"{x:.17g}" for x in a)  # noqa: E731
    nx, ny, nz = points
    return f"""<mujoco model="pushplan_flex">
  <option timestep="{timestep:.17g}" cone="elliptic" integrator="discrete" gravity="{v(gravity)}"/>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.01" pos="0 0 {scene.lower_centre[2]:.17g}" friction="{mu:.17g} 0 0"/>
    <body name="gripper" mocap="true" pos="{v(up)}" quat="{v(q)}"/>
    <body name="pad" pos="{v(centre)}" quat="{v(q)}">
      <freejoint/>
      <geom type="box" size="{radius:.6g} {radius:.6g} {radius:.6g}" mass="{scene.block_mass:.6g}"
            contype="0" conaffinity="0"/>
      <flexcomp name="block" type="grid" dim="3" count="{nx} {ny} {nz}" spacing="{v(spacing)}"
                radius="{radius:.6g}" mass="{scene.block_mass:.17g}" dof="full">
        <contact condim="3" friction="{mu:.17g} 0 0" priority="1" selfcollide="none"/>
        <elasticity young="{s.young:.17g}" poisson="{s.poisson:.17g}" damping="{FLEX_DAMPING:g}"/>
        <edge equality="false"/>
        <pin gridrange="0 0 {nz - 1} {nx - 1} {ny - 1} {nz - 1}"/>
      </flexcomp>
    </body>
  </worldbody>
  <equality><weld body1="gripper" body2="pad" solref="{WELD_TIMECONST_STEPS * timestep:.17g} 1"/></equality>
</mujoco>
"""


def _flex_run(scene, commands, traj, n_move, n_settle, points, mu) -> list[dict]:
    mj = _mujoco()
    src, _ = _load_model(scene.source)
    m = mj.MjModel.from_xml_string(flex_mjcf(scene, points, mu, src.opt.timestep, src.opt.gravity))
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    x0 = d.flexvert_xpos.copy()
    z = x0[:, 2]
    lower = np.flatnonzero(np.isclose(z, z.min(), atol=1e-9 * scene.scenario.size[2]))
    upper = np.flatnonzero(np.isclose(z, z.max(), atol=1e-9 * scene.scenario.size[2]))
    local = scene.to_fe(x0 - scene.lower_centre)
    # trapezoidal tributary weights of a regular grid face: half on edges, quarter at corners
    w = np.ones(x0.shape[0])
    for ax in (0, 1):
        edge = np.isclose(local[:, ax], local[:, ax].min()) | np.isclose(local[:, ax], local[:, ax].max())
        w[edge] *= 0.5
    g0 = np.array(m.body_pos[m.body("gripper").id])
    drive = traj.upper_centre - traj.upper_centre[0]
    turn = traj.upper_yaw - traj.upper_yaw[0]
    out, scale = [], max(scene.scenario.size)
    for k in range(len(commands)):
        for j in range(1, n_move + n_settle + 1):
            s = min(j / n_move, 1.0)
            d.mocap_pos[0] = g0 + (1 - s) * drive[k] + s * drive[k + 1]
            d.mocap_quat[0] = _quat_z(scene.yaw + (1 - s) * turn[k] + s * turn[k + 1])
            mj.mj_step(m, d)
        mj.mj_kinematics(m, d)
        mj.mj_flex(m, d)
        x = d.flexvert_xpos
        disp = x - x0
        low = (w[lower, None] * disp[lower]).sum(0) / w[lower].sum()
        up = (w[upper, None] * disp[upper]).sum(0) / w[upper].sum()
        dl = local[lower] - local[lower].mean(0)
        cur = scene.to_fe(x[lower] - x[lower].mean(0))
        yaw = math.atan2(np.sum(w[lower] * (dl[:, 0] * cur[:, 1] - dl[:, 1] * cur[:, 0])),
                         np.sum(w[lower] * (dl[:, 0] * cur[:, 0] + dl[:, 1] * cur[:, 1])))
        out.append(_record(k + 1, drive[k + 1], up, low, yaw, scale))
    return out


def _summary(records: list[dict]) -> dict:
    last = records[-1] if records else {}
    return {
        "final_twist_deg": last.get("twist_deg", 0.0),
        "final_deviation_deg": last.get("deviation_deg", 0.0),
        "max_abs_twist_deg": max((abs(r["twist_deg"]) for r in records), default=0.0),
        "max_abs_deviation_deg": max((abs(r["deviation_deg"]) for r in records), default=0.0),
        "final_lower": last.get("lower"),
    }


MODEL_NOTES = {
    "fe": "this FE model: deformable block, anisotropic elliptic friction, displacement-driven upper face",
    "rigid_weld": "MuJoCo rigid box with the MJCF <pair> friction, welded to the mocap gripper (stiff weld)",
    "rigid_force": "MuJoCo rigid box with the MJCF <pair> friction, pushed by a horizontal force at its "
                   "centre of mass (force_factor x sliding threshold, until it travelled the command length)",
    "flex_isotropic": "MuJoCo 3D flex of the block's size and material, top pinned to the gripper, "
                      "isotropic friction flex_mu (MuJoCo flex contacts take no anisotropy)",
}


def compare(scene: MjcfScene, commands: Sequence[Command] | None = None, settings: BridgeSettings | None = None,
            fe_model: Model | None = None, models: Sequence[str] = tuple(MODEL_NOTES), out_dir=None) -> dict:
    """Same commands through our FE model and MuJoCo's rigid and flex models.

    Each model reports per command: ``drive`` (gripper-carried upper-face centre
    displacement, or the commanded one), ``upper`` / ``lower`` (block face centroid
    displacements), ``twist_deg`` (upper to lower: the block's deformation twist),
    ``deviation_deg`` (drive to lower), all world frame, m / degrees.

    With ``out_dir``, writes ``comparison.json`` and ``comparison.png`` (lower-face
    trajectories).  Raises ValueError for an unknown model name or no commands.
    """
    settings = settings or BridgeSettings(scene=scene.source)
    commands = tuple(scene.scenario.commands if commands is None else commands)
    if not commands:
        raise InputError("no commands: give a command list or a scenario with [[load]] steps")
    unknown = [name for name in models if name not in MODEL_NOTES]
    if unknown:
        raise InputError(f"unknown comparison model {unknown[0]!r} (known: {', '.join(MODEL_NOTES)})")
    if not scene.source:
        raise InputError("compare needs a scene imported from an MJCF file")
    m, _ = _load_model(scene.source)
    traj = gripper_trajectory(scene, m, commands, settings.gripper, settings.control_period)
    n_move = max(1, int(round(settings.control_period / m.opt.timestep)))
    n_settle = int(round(settings.settle_time / m.opt.timestep))
    s = scene.scenario
    flex_mu = settings.flex_mu if settings.flex_mu is not None else math.sqrt(s.mu_x * s.mu_y)
    runners = {
        "fe": lambda: _fe_run(scene, commands, fe_model or s.model()),
        "rigid_weld": lambda: _rigid_weld_run(scene, traj, n_move, n_settle),
        "rigid_force": lambda: _rigid_force_run(scene, commands, traj, n_move, n_settle, settings.force_factor),
        "flex_isotropic": lambda: _flex_run(scene, commands, traj, n_move, n_settle, settings.flex_points, flex_mu),
    }
    result = {
        "scene": scene.summary(), "settings": {k: getattr(settings, k) for k in BridgeSettings.__dataclass_fields__},
        "flex_mu": flex_mu,
        "commands": [{"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": math.degrees(c.dtheta)} for c in commands],
        "models": {},
    }
    for name in models:
        t0 = time.perf_counter()
        records = runners[name]()
        result["models"][name] = {"description": MODEL_NOTES[name], "wall_s": time.perf_counter() - t0,
                                  "summary": _summary(records), "steps": records}
    if out_dir is not None:
        out = Path(out_dir)
        atomic_write_json(out / "comparison.json", result)
        atomic_write_bytes(out / "comparison.png", _plot(result))
    return result


def _plot(result: dict) -> bytes:
    """PNG of the lower-face centroid trajectories (mm) of every model."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 5))
    first = next(iter(result["models"].values()))
    drive = np.array([[0.0, 0.0]] + [r["drive"][:2] for r in first["steps"]]) * 1e3
    ax.plot(drive[:, 0], drive[:, 1], "k--", label="drive (upper face)")
    for name, res in result["models"].items():
        xy = np.array([[0.0, 0.0]] + [r["lower"][:2] for r in res["steps"]]) * 1e3
        ax.plot(xy[:, 0], xy[:, 1], "o-", ms=3,
                label=f"{name}: twist {res['summary']['final_twist_deg']:.2f}°, "
                      f"deviation {res['summary']['final_deviation_deg']:.2f}°")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("lower-face centroid")
    ax.legend(fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


# ---------------------------------------------------------------- CLI


def _cli_scene(args) -> tuple[MjcfScene, BridgeSettings]:
    scene, settings = open_scene(args.scene, block=args.block, floor=args.floor)
    if getattr(args, "gripper", None):
        settings = replace(settings, gripper=args.gripper)
    if getattr(args, "control_period", None) is not None:
        settings = replace(settings, control_period=args.control_period)
    return scene, settings


def _cli_commands(args, scene: MjcfScene) -> tuple[Command, ...]:
    if getattr(args, "commands", None):
        from ..config.commands import load_commands

        return tuple(load_commands(args.commands))
    if not scene.scenario.commands:
        raise InputError("no commands: give --commands plan.json or a scenario TOML with [[load]] steps")
    return scene.scenario.commands


def _cli_model(args, scene: MjcfScene) -> Model:
    return scene.scenario.model(elements=tuple(args.elements) if args.elements else None,
                                quadrature=args.quadrature)


def _cmd_import(args) -> int:
    scene, _ = _cli_scene(args)
    s = scene.scenario
    print(f"block {scene.block_body!r} ({scene.block_geom}): size {[round(v * 1e3, 6) for v in s.size]} mm, "
          f"mass {scene.block_mass * 1e3:.4g} g")
    print(f"friction ({scene.pair or 'dynamic contact'}): mu_x = {s.mu_x}, mu_y = {s.mu_y}, angle = {s.angle_deg} deg")
    print(f"material: E = {s.young:.4g} Pa, nu = {s.poisson}")
    for k, v in scene.from_mjcf.items():
        print(f"  from MJCF: {k} <- {v}")
    for k, v in scene.not_from_mjcf.items():
        print(f"  not from MJCF: {k} <- {v}")
    for note in scene.notes:
        print(f"  note: {note}")
    return 0


def _cmd_compare(args) -> int:
    from ..outputs.atomic import prepare_output_dir

    scene, settings = _cli_scene(args)
    commands = _cli_commands(args, scene)
    models = [name for name in MODEL_NOTES if not (args.no_flex and name == "flex_isotropic")]
    fe_model = _cli_model(args, scene)
    out = prepare_output_dir(args.out)
    try:
        result = compare(scene, commands, settings, fe_model, models, out)
    except RuntimeError as exc:
        import sys

        print(f"pushplan: solver failure: {exc}", file=sys.stderr)
        return 3
    print(f"{'model':>15} {'lower x,y (mm)':>20} {'twist':>9} {'deviation':>10} {'wall':>7}")
    for name, res in result["models"].items():
        sm = res["summary"]
        lo = np.asarray(sm["final_lower"]) * 1e3
        print(f"{name:>15} {lo[0]:>9.4f},{lo[1]:>9.4f} {sm['final_twist_deg']:>8.3f}° "
              f"{sm['final_deviation_deg']:>9.3f}° {res['wall_s']:>6.2f}s")
    print(f"wrote {out / 'comparison.json'} and {out / 'comparison.png'}")
    return 0


def _cmd_cosim(args) -> int:
    import sys

    from ..outputs.atomic import prepare_output_dir

    scene, settings = _cli_scene(args)
    commands = _cli_commands(args, scene)
    out = prepare_output_dir(args.out)
    record = run_cosimulation(scene, commands, settings.gripper, settings.control_period, _cli_model(args, scene),
                              rrd_path=None if args.no_rerun else out / "cosim.rrd")
    atomic_write_json(out / "cosim.json", record)
    for p in record["periods"]:
        lo = np.asarray(p["fe_lower_centroid"]) * 1e3
        print(f"period {p['period']:>3} t = {p['time']:.3f} s  lower {lo[0]:8.4f},{lo[1]:8.4f} mm  "
              f"twist {p['fe_twist_deg']:7.3f}°  FE {p['fe_step_s'] * 1e3:6.1f} ms")
    print(f"co-simulation rate: {record['rate_periods_per_s']:.2f} control periods/s "
          f"({len(record['periods'])} periods, {record['mujoco_steps_per_period']} MuJoCo steps each, "
          f"{record['wall_s']:.2f} s)")
    print(f"wrote {out / 'cosim.json'}" + ("" if args.no_rerun else f" and {out / 'cosim.rrd'}"))
    if record["status"] != "completed":
        print(f"pushplan: solver failure at period {len(record['periods'])}", file=sys.stderr)
        return 3
    return 0


def _cmd_export(args) -> int:
    scene, settings = _cli_scene(args)
    commands = _cli_commands(args, scene)
    path = export_plan(args.out, scene, commands, settings.gripper, settings.control_period)
    print(f"wrote {path} ({len(commands) + 1} gripper knots, {settings.control_period} s apart)")
    return 0


def register(subparsers) -> None:
    """Add ``pushplan mujoco {import,compare,cosim,export}``."""
    p = subparsers.add_parser("mujoco", help="MuJoCo bridge: MJCF import, rigid/flex comparison, "
                                             "co-simulation, plan export")
    sub = p.add_subparsers(dest="mujoco_command", metavar="ACTION")
    sub.required = True

    def common(q, commands=True, fe=True):
        q.add_argument("scene", help="scenario TOML with a [mujoco] table, or an MJCF .xml")
        q.add_argument("--block", help="block body or box geom (default from [mujoco] or 'block')")
        q.add_argument("--floor", help="floor plane geom (default from [mujoco] or 'floor')")
        if commands:
            q.add_argument("--gripper", help="gripper mocap body (default from [mujoco] or 'gripper')")
            q.add_argument("--commands", help="plan.json whose commands replace the scenario's [[load]]")
            q.add_argument("--control-period", type=float, help="s of MuJoCo time per command")
        if fe:
            q.add_argument("--elements", type=int, nargs=3, metavar=("NX", "NY", "NZ"), help="FE mesh override")
            q.add_argument("--quadrature", type=int, choices=(2, 3), help="Gauss points per direction override")

    q = sub.add_parser("import", help="show what the MJCF scene gives the FE model")
    common(q, commands=False, fe=False)
    q.set_defaults(func=_cmd_import)
    q = sub.add_parser("compare", help="FE vs MuJoCo rigid (weld, force) vs flex (isotropic) on the same commands")
    common(q)
    q.add_argument("--out", required=True, help="output folder (comparison.json, comparison.png)")
    q.add_argument("--no-flex", action="store_true", help="skip the flex model")
    q.set_defaults(func=_cmd_compare)
    q = sub.add_parser("cosim", help="headless co-simulation: gripper follows the commands, FE block in MuJoCo")
    common(q)
    q.add_argument("--out", required=True, help="output folder (cosim.json, cosim.rrd)")
    q.add_argument("--no-rerun", action="store_true", help="do not write the rerun recording")
    q.set_defaults(func=_cmd_cosim)
    q = sub.add_parser("export", help="write a plan as MuJoCo gripper keyframes (.xml) or times and poses (.npz)")
    common(q, fe=False)
    q.add_argument("--out", required=True, help="output file, .xml (MJCF <keyframe>) or .npz")
    q.set_defaults(func=_cmd_export)
