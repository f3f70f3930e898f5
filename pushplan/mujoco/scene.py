"""MJCF scene import: an FE scenario from a MuJoCo scene (block size, friction,
material) and where the block sits in it (:class:`MjcfScene`).

MuJoCo facts this import rests on (MuJoCo 4.0, checked with ``data.contact``):

* Anisotropic friction exists only on a geom-geom ``<pair condim="3"
  friction="f1 f2 ...">`` with ``cone="elliptic"``; ``f1`` acts along the contact
  tangent ``t1``, ``f2`` along ``t2``.  For a box on a horizontal plane the frame is
  built from the normal alone: ``t1 = world +y``, ``t2 = world -x`` whatever the yaw
  of either body.  :func:`scene_from_mjcf` reads the frame of the actual contacts
  and maps it to our ``(mu_x, mu_y, angle)`` in the block's own frame.
* ``<custom><numeric name="pushplan_friction_angle" data="deg"/>`` turns those axes
  about world z for the FE model (the floor's orthotropy axes at an angle without
  yawing the box); MuJoCo's own contacts are not turned (its frame is fixed).
* A box resting exactly at its half height may have no MuJoCo contact at ``qpos0``
  (distance 0 rounds to +1e-19 m when yawed): the import looks for the contacts with
  the block-floor margin raised to :data:`RESTING_GAP_REL` x the block height.

Frames: the FE model (``fe_contact``) has the block's lower face on ``z = 0``
centred on its origin, axes along the block's edges.  The MuJoCo block's reference
pose (at ``qpos0``) fixes that frame in the world: origin at the lower-face centre
``MjcfScene.lower_centre``, rotated by ``MjcfScene.yaw`` about world z.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fe_contact import GRAVITY, SolverOptions

from ..config.mujoco import BridgeSettings, bridge_settings
from ..config.scenario import Scenario, load_scenario
from ..errors import InputError, InputWarning
from .frames import matrix_yaw, quat_mul, quat_z, rz
from .mjmodel import find_object, load_model, mujoco_module, object_name

NUMERIC_YOUNG = "pushplan_young"
NUMERIC_POISSON = "pushplan_poisson"
NUMERIC_FRICTION_ANGLE = "pushplan_friction_angle"
"""``<custom><numeric>``: world angle (deg, about +z from world x) of the friction axis
that MuJoCo's ``<pair friction="f1 f2 ...">`` puts along world x (``f2``); ``f1`` acts
90 deg further.  Absent: 0 (MuJoCo's own frame)."""
RESTING_GAP_REL = 1e-6
"""Gap between the block's lower face and the floor at ``qpos0``, as a fraction of the
block height, still taken as resting contact (MuJoCo drops a contact at distance 0
once rounding puts it at +1e-19 m: a yawed box at exactly its half height)."""
DEFAULT_ELEMENTS = (8, 8, 4)
DEFAULT_QUADRATURE = 2
VERTICAL_TOL = 1e-9
"""|1 - |R_zz|| above which a floor normal or block axis is not vertical."""
FRAME_TOL = 1e-9
"""Spread of the contact frames / frictions of one pair above which they differ."""
FROM_MJCF = {
    "friction.mu_x": "contact friction along the tangent nearer the block x edge",
    "friction.mu_y": "contact friction along the other tangent",
    "friction.angle_deg": "MuJoCo contact frame (world-fixed) seen from the block frame",
}


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
        return np.asarray(v, float) @ rz(self.yaw).T

    def to_fe(self, v: np.ndarray) -> np.ndarray:
        """Rotate world vectors ``(..., 3)`` into the FE frame."""
        return np.asarray(v, float) @ rz(self.yaw)

    def body_pose(self, lower_displacement, lower_yaw: float) -> tuple[np.ndarray, np.ndarray]:
        """World (pos (3,), quat (4,)) of the block body for an FE lower-face pose:
        centroid displacement (3,) in the FE frame (m) and yaw (rad) from the reference."""
        pos = (self.lower_centre + self.to_world(lower_displacement)
               + rz(lower_yaw) @ (self.body_pos - self.lower_centre))
        return pos, quat_mul(quat_z(lower_yaw), self.body_quat)

    def mj_model(self, what: str):
        """The ``MjModel`` of :attr:`source`; ``what`` names the caller in the error.

        Raises
        ------
        InputError
            The scene was imported from an ``MjModel``, not a file.
        """
        if not self.source:
            raise InputError(f"{what} needs a scene imported from an MJCF file")
        return load_model(self.source)[0]

    def to_dict(self) -> dict:
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


def block_geom_pose(m, d, scene: MjcfScene) -> tuple[np.ndarray, np.ndarray, float]:
    """(lower-face centre (3,), upper-face centre (3,), yaw) of the MuJoCo block geom
    in ``d``, world frame, m and rad."""
    gid = find_object(m, mujoco_module().mjtObj.mjOBJ_GEOM, scene.block_geom, "block geom")
    R = d.geom_xmat[gid].reshape(3, 3)
    half = 0.5 * scene.scenario.size[2] * R[:, 2] * np.sign(R[2, 2])
    return d.geom_xpos[gid] - half, d.geom_xpos[gid] + half, matrix_yaw(R)


def _block_ids(m, block: str) -> tuple[int, int]:
    """(body id, box geom id) of ``block``, a box geom or a body holding one."""
    mj = mujoco_module()
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


def _numeric(m, name: str) -> float | None:
    """The one finite number of ``<custom><numeric name=name>``, or None when absent.

    Raises
    ------
    InputError
        The numeric holds other than one finite number.
    """
    try:
        data = np.asarray(m.numeric(name).data, float)
    except KeyError:
        return None
    if data.size != 1 or not np.isfinite(data[0]):
        raise InputError(f"<numeric name={name!r}> must hold one finite number, got {data.tolist()}")
    return float(data[0])


def _material(m, base: Scenario | None, from_mjcf: dict, not_from: dict) -> tuple[float, float]:
    """(young Pa, poisson) from ``<numeric>`` fields, else from ``base``; records where from."""
    out = {}
    for key, numeric in (("young", NUMERIC_YOUNG), ("poisson", NUMERIC_POISSON)):
        value = _numeric(m, numeric)
        if value is not None:
            out[key] = value
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


def _resting_contacts(m, d, bgeom: int, fgeom: int) -> None:
    """``mj_forward`` at ``qpos0`` with the block-floor margin raised to
    :data:`RESTING_GAP_REL` x the block height (the model's margins are restored)."""
    mj = mujoco_module()
    tol = RESTING_GAP_REL * 2.0 * float(m.geom_size[bgeom][2])
    pairs = [i for i in range(m.npair) if sorted((m.pair_geom1[i], m.pair_geom2[i])) == sorted((bgeom, fgeom))]
    saved = m.geom_margin[bgeom].copy(), m.pair_margin[pairs].copy()
    m.geom_margin[bgeom] = max(float(saved[0]), tol)
    m.pair_margin[pairs] = np.maximum(saved[1], tol)
    try:
        mj.mj_forward(m, d)
    finally:
        m.geom_margin[bgeom], m.pair_margin[pairs] = saved


def _contact(m, d, bgeom: int, fgeom: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(frame (3, 3), friction (5,), condim) shared by the block-floor contacts at qpos0,
    found within :data:`RESTING_GAP_REL` of the block height."""
    mj = mujoco_module()
    _resting_contacts(m, d, bgeom, fgeom)
    geoms = np.sort(np.asarray(d.contact.geom[: d.ncon]).reshape(-1, 2), axis=1)
    mine = np.flatnonzero((geoms == sorted((bgeom, fgeom))).all(axis=1))
    if mine.size == 0:
        raise InputError(
            f"block geom {object_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} does not touch floor "
            f"{object_name(m, mj.mjtObj.mjOBJ_GEOM, fgeom)!r} at qpos0 (gap tolerance {RESTING_GAP_REL:g} x the "
            "block height); rest the block on the floor"
        )
    frames = np.asarray(d.contact.frame[: d.ncon])[mine].reshape(-1, 3, 3)
    fric = np.asarray(d.contact.friction[: d.ncon])[mine]
    dims = np.asarray(d.contact.dim[: d.ncon])[mine]
    with np.errstate(invalid="ignore", over="ignore"):  # an inf friction is refused by the caller
        spread = max(np.ptp(frames, axis=0).max(), np.nan_to_num(np.ptp(fric, axis=0)).max())
    if spread > FRAME_TOL or np.ptp(dims) > 0:
        raise InputError("the block-floor contacts disagree on frame, friction or condim")
    if abs(abs(frames[0][0, 2]) - 1.0) > VERTICAL_TOL:
        raise InputError(f"block-floor contact normal {frames[0][0].tolist()} is not vertical; the FE plane is z = 0")
    return frames[0], fric[0], int(dims[0])


def _pair_attribute(source: str, m, index: int) -> str | None:
    """The ``friction`` text of the ``index``-th ``<pair>`` in the MJCF file ``source``
    (None: no file, no such element in it, or no attribute)."""
    import xml.etree.ElementTree as ET

    if not source:
        return None
    try:
        pairs = ET.parse(source).getroot().findall("./contact/pair")
    except (OSError, ET.ParseError):
        return None
    return pairs[index].get("friction") if index < len(pairs) and len(pairs) == m.npair else None


def _check_pair_friction(m, index: int, name: str, used, dim: int, source: str) -> None:
    """The friction MuJoCo compiled for the pair is what the MJCF says, finite and
    >= 0, and what its contacts use: MuJoCo replaces an unreadable ``friction``
    (``nan``) by its default 1 and clamps a negative one to 1e-5, silently."""
    compiled = np.asarray(m.pair_friction[index], float)
    text = _pair_attribute(source, m, index)
    label = f"<pair name={name!r}> friction"
    if text is not None:
        try:
            given = [float(v) for v in text.split()]
        except ValueError:
            raise InputError(f"{label} {text!r} in {source} is not a list of numbers") from None
        if not all(math.isfinite(v) and v >= 0.0 for v in given):
            raise InputError(f"{label} {text!r} in {source} must be finite and >= 0")
        if not np.array_equal(compiled[:len(given)], given):
            raise InputError(f"{label} {text!r} in {source}: MuJoCo compiled {compiled.tolist()} instead")
    if not (np.isfinite(compiled).all() and (compiled >= 0.0).all()):
        raise InputError(f"{label} compiled by MuJoCo is {compiled.tolist()}: must be finite and >= 0")
    k = max(dim - 1, 0)
    if not np.array_equal(np.asarray(used, float)[:k], compiled[:k]):
        raise InputError(f"{label} {compiled[:k].tolist()} is used by MuJoCo's contacts as {list(used[:k])}")


def _friction(m, d, bgeom: int, fgeom: int, yaw: float, notes: list,
              source: str = "") -> tuple[float, float, float, str | None]:
    """(mu_x, mu_y, angle_deg, pair) from the block-floor contacts at qpos0; the
    pair's friction checked against the MJCF ``source`` file (see
    :func:`_check_pair_friction`)."""
    mj = mujoco_module()
    frame, f, dim = _contact(m, d, bgeom, fgeom)
    pairs = [i for i in range(m.npair) if sorted((m.pair_geom1[i], m.pair_geom2[i])) == sorted((bgeom, fgeom))]
    pair = object_name(m, mj.mjtObj.mjOBJ_PAIR, pairs[0]) if pairs else None
    if pairs:
        _check_pair_friction(m, pairs[0], pair, f, dim, source)
    if pair is None:
        notes.append("no <pair> for block and floor: friction is MuJoCo's isotropic mix of the geom frictions")
    if m.opt.cone != mj.mjtCone.mjCONE_ELLIPTIC:
        notes.append("opt.cone is pyramidal: MuJoCo approximates the elliptic cone of the FE model")
    if dim == 1:
        notes.append("condim = 1: frictionless contact")
        return 0.0, 0.0, 0.0, pair
    if dim > 3:
        notes.append(f"condim = {dim}: torsional/rolling friction {f[2:].tolist()} has no FE counterpart (ignored)")
    turn = _numeric(m, NUMERIC_FRICTION_ANGLE)
    if turn is not None:
        notes.append(f"friction axes turned by {turn:g} deg in the FE model (<numeric name="
                     f"'{NUMERIC_FRICTION_ANGLE}'>); MuJoCo's own contacts keep f2 along world x")
    # tangents (turned by the numeric's angle about world z) in the FE frame;
    # t_x is the one nearer the block's x edge
    turned = rz(math.radians(turn or 0.0))
    t1 = (turned @ frame[1]) @ rz(yaw)
    t2 = (turned @ frame[2]) @ rz(yaw)
    if abs(t1[0]) >= abs(t2[0]):
        mu_x, mu_y, tx = float(f[0]), float(f[1]), t1
    else:
        mu_x, mu_y, tx = float(f[1]), float(f[0]), t2
    angle = math.degrees(math.atan2(tx[1], tx[0]))
    angle = (angle + 90.0) % 180.0 - 90.0  # an ellipse axis is defined modulo 180 deg
    return mu_x, mu_y, 0.0 if abs(angle) < 1e-9 else angle, pair


def _box_on_plane(m, d, bgeom: int, fgeom: int, floor: str) -> tuple[tuple[float, float, float], float, np.ndarray]:
    """(size (m), yaw (rad), lower-face centre (3,)) of an upright box geom on a horizontal plane."""
    mj = mujoco_module()
    if m.geom_type[bgeom] != mj.mjtGeom.mjGEOM_BOX:
        raise InputError(f"block geom {object_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} must be a box")
    if m.geom_type[fgeom] != mj.mjtGeom.mjGEOM_PLANE:
        raise InputError(f"floor geom {floor!r} must be a plane")
    Rf = d.geom_xmat[fgeom].reshape(3, 3)
    if abs(Rf[2, 2] - 1.0) > VERTICAL_TOL:
        raise InputError(f"floor {floor!r} normal {Rf[:, 2].tolist()} is not world +z")
    Rb = d.geom_xmat[bgeom].reshape(3, 3)
    if abs(abs(Rb[2, 2]) - 1.0) > VERTICAL_TOL:
        raise InputError(f"block geom z axis {Rb[:, 2].tolist()} is not vertical; stand the box upright")
    size = tuple(float(2 * v) for v in m.geom_size[bgeom])
    return size, matrix_yaw(Rb), d.geom_xpos[bgeom] - np.array([0.0, 0.0, size[2] / 2])


def _density(m, bbody: int, size, base: Scenario | None, from_mjcf: dict, notes: list) -> float:
    """Block density, kg/m^3: the MJCF block body's mass over the box volume (a geom's
    ``density`` or ``mass``, or the body's ``<inertial mass>``), unless the scenario
    TOML gives ``material.density`` > 0, which wins (an ``InputWarning`` when it differs).
    The FE self-weight is then ``rho g V`` (``fe_contact`` gravity); a MuJoCo gravity of
    another size is noted."""
    mj = mujoco_module()
    rho = float(m.body_mass[bbody]) / math.prod(size)
    from_mjcf["material.density"] = "block body mass / box volume"
    g = float(np.linalg.norm(m.opt.gravity))
    if not math.isclose(g, GRAVITY, rel_tol=1e-9):
        notes.append(f"MuJoCo gravity {g:g} m/s^2; the FE self-weight uses {GRAVITY} m/s^2")
    if base is None or base.density <= 0:
        return rho
    if not math.isclose(base.density, rho, rel_tol=1e-9):
        body = object_name(m, mj.mjtObj.mjOBJ_BODY, bbody)
        warnings.warn(InputWarning(
            f"material.density = {base.density:g} kg/m^3 in the scenario overrides the MJCF block {body!r}'s "
            f"{rho:g} kg/m^3 (body mass / box volume)"), stacklevel=3)
    from_mjcf.pop("material.density")
    return base.density


def _scenario(path: str, base: Scenario | None, size, friction, material, notes: list) -> Scenario:
    """The imported scenario: MJCF size, friction and material (young, poisson,
    density), the rest from ``base`` or defaults."""
    mu_x, mu_y, angle = friction
    young, poisson, density = material
    if base is not None:
        for key, ours, theirs in (
            ("block.size", size, tuple(base.size)), ("friction.mu_x", mu_x, base.mu_x),
            ("friction.mu_y", mu_y, base.mu_y), ("friction.angle_deg", angle, base.angle_deg),
        ):
            if not np.allclose(ours, theirs, rtol=1e-9, atol=1e-12):
                notes.append(f"scenario {key} {theirs} replaced by the MJCF value {ours}")
        return replace(base, size=size, young=young, poisson=poisson, density=density, mu_x=mu_x, mu_y=mu_y,
                       angle_deg=angle)
    return Scenario(name=Path(path).stem if path else "mjcf", size=size, elements=DEFAULT_ELEMENTS,
                    quadrature=DEFAULT_QUADRATURE, young=young, poisson=poisson, density=density, mu_x=mu_x,
                    mu_y=mu_y, angle_deg=angle, commands=(), solver=SolverOptions(local_method="newton"),
                    description=f"imported from {path or 'an MjModel'}", extra={})


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
        material when the MJCF has no ``<custom><numeric name="pushplan_young">`` (Pa) /
        ``"pushplan_poisson"``.  ``"pushplan_friction_angle"`` (deg) turns the friction
        axes (see the module docstring).  MJCF values replace the base's size and friction
        (differences are listed in ``notes``).  The density is the block body's mass over
        the box volume unless the base gives one (> 0), which wins with an ``InputWarning``
        when it differs.

    Returns
    -------
    MjcfScene

    Raises
    ------
    InputError
        Missing file or name, block not a vertical box resting on the floor, floor
        not a horizontal plane, missing or bad material.
    """
    mj = mujoco_module()
    m, path = load_model(source)
    bbody, bgeom = _block_ids(m, block)
    fgeom = find_object(m, mj.mjtObj.mjOBJ_GEOM, floor, "floor geom")
    d = mj.MjData(m)
    mj.mj_forward(m, d)  # kinematics; the contacts are found in _friction (resting-gap tolerance)
    size, yaw, lower = _box_on_plane(m, d, bgeom, fgeom, floor)
    notes: list[str] = []
    mu_x, mu_y, angle, pair = _friction(m, d, bgeom, fgeom, yaw, notes, path)
    from_mjcf = {"block.size": f"box geom {object_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom)!r} (2 x size)", **FROM_MJCF}
    if _numeric(m, NUMERIC_FRICTION_ANGLE) is not None:
        from_mjcf["friction.angle_deg"] += f", turned by <numeric name='{NUMERIC_FRICTION_ANGLE}'>"
    not_from: dict[str, str] = {}
    material = (*_material(m, base, from_mjcf, not_from), _density(m, bbody, size, base, from_mjcf, notes))
    not_from.update(dict.fromkeys(("block.elements", "block.quadrature", "solver", "load"),
                                  "scenario" if base is not None else "default"))
    scenario = _scenario(path, base, size, (mu_x, mu_y, angle), material, notes)
    gap = d.geom_xpos[bgeom][2] - size[2] / 2 - d.geom_xpos[fgeom][2]
    if abs(gap) > 1e-9 * size[2]:
        notes.append(f"block lower face is {gap:.3g} m from the floor at qpos0; the FE model starts in contact")
    notes.append("MuJoCo contact softness (solref, solimp, margin) has no FE counterpart")
    return MjcfScene(
        scenario=scenario, source=path,
        block_body=object_name(m, mj.mjtObj.mjOBJ_BODY, bbody), block_geom=object_name(m, mj.mjtObj.mjOBJ_GEOM, bgeom),
        floor_geom=object_name(m, mj.mjtObj.mjOBJ_GEOM, fgeom), pair=pair,
        lower_centre=np.array(lower), yaw=yaw, body_pos=d.xpos[bbody].copy(), body_quat=d.xquat[bbody].copy(),
        block_mass=float(m.body_subtreemass[bbody]), from_mjcf=from_mjcf, not_from_mjcf=not_from,
        notes=tuple(notes),
    )


def open_scene(path, block: str | None = None, floor: str | None = None) -> tuple[MjcfScene, BridgeSettings]:
    """Open a scenario TOML with a ``[mujoco]`` table, or a bare MJCF file.

    A TOML's ``mujoco.scene`` is relative to the TOML; a bare MJCF gets default
    mesh and solver settings and no load steps.  ``block`` / ``floor`` override
    the settings' names.

    Raises
    ------
    InputError
        Unknown suffix, no ``[mujoco]`` table or ``mujoco.scene``, bad settings or scene.
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
