"""Access to compiled MuJoCo models: the lazy ``mujoco`` import, loading an MJCF file,
object names and ids (unnamed objects as ``"#id"``) and the world frame of a body or site.

``mujoco`` is imported inside functions only, so importing this package stays cheap.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError


def mujoco_module():
    """The ``mujoco`` module, imported on first use."""
    import mujoco

    return mujoco


def object_name(m, objtype, i: int) -> str:
    """Name of object ``i`` of type ``objtype``, or ``"#i"`` when unnamed."""
    name = mujoco_module().mj_id2name(m, objtype, i)
    return name if name else f"#{i}"


def geom_label(m, g: int) -> str:
    """A name for geom ``g`` usable in a recording path: its own, else ``<body>_geom<g>``
    (``body<b>_geom<g>`` when the body is unnamed too)."""
    mj = mujoco_module()
    name = mj.mj_id2name(m, mj.mjtObj.mjOBJ_GEOM, g)
    if name:
        return name
    b = int(m.geom_bodyid[g])
    return f"{mj.mj_id2name(m, mj.mjtObj.mjOBJ_BODY, b) or f'body{b}'}_geom{g}"


def find_object(m, objtype, name: str, what: str) -> int:
    """Id of the object called ``name`` (or ``"#id"``, as :func:`object_name` writes it).

    Raises
    ------
    InputError
        No such object; ``what`` names its role in the message.
    """
    mj = mujoco_module()
    if name.startswith("#") and name[1:].isascii() and name[1:].isdigit():
        kind = str(mj.mjtObj(objtype).name).removeprefix("mjOBJ_").lower()  # "geom", "body", "site"
        n = int(getattr(m, f"n{kind}"))
        i = int(name[1:]) if len(name) <= 20 else n
        if not i < n:
            raise InputError(f"{what} {name[:24]!r}: the MJCF model has {n} {kind}(s), numbered #0 to #{n - 1}")
        return i
    i = mj.mj_name2id(m, objtype, name)
    if i < 0:
        raise InputError(f"{what} {name!r} not found in the MJCF model")
    return i


def load_model(source) -> tuple[Any, str]:
    """(``MjModel``, path) of an MJCF file, or (``source``, "") for a compiled model.

    Raises
    ------
    InputError
        Missing file, the checks of :func:`~pushplan.mujoco.mjcf_check.check_mjcf`, or
        MuJoCo rejects it (its message quoted, on one line).
    """
    mj = mujoco_module()
    if isinstance(source, mj.MjModel):
        return source, ""
    from .mjcf_check import check_mjcf

    path = Path(source)
    if not path.exists():
        raise InputError(f"MJCF file not found: {path}")
    check_mjcf(path)  # size, XML, finite numbers: before MuJoCo reads its defaults for them
    try:
        return mj.MjModel.from_xml_path(str(path)), str(path)
    except ValueError as exc:  # MuJoCo's compiler error: the file is bad input (one line)
        raise InputError(f"cannot load MJCF {path}: {' '.join(str(exc).split())}") from None


def frame_of(m, d, name: str) -> tuple[str, int, np.ndarray, np.ndarray]:
    """(``"body"`` | ``"site"``, id, world position (3,) m, rotation (3, 3)) of a body or site.

    Raises
    ------
    InputError
        ``name`` is neither a body nor a site.
    """
    mj = mujoco_module()
    bid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, name)
    if bid >= 0:
        return "body", bid, d.xpos[bid].copy(), d.xmat[bid].reshape(3, 3).copy()
    sid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_SITE, name)
    if sid >= 0:
        return "site", sid, d.site_xpos[sid].copy(), d.site_xmat[sid].reshape(3, 3).copy()
    raise InputError(f"gripper {name!r} is neither a body nor a site of the MJCF model")


def mocap_index(m, name: str, what: str = "gripper") -> int:
    """Index into ``MjData.mocap_pos`` of the mocap body ``name``.

    Raises
    ------
    InputError
        ``name`` is not a mocap body.
    """
    mj = mujoco_module()
    bid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, name)
    if bid < 0 or m.body_mocapid[bid] < 0:
        raise InputError(f"{what} {name!r} must be a mocap body to follow a command list")
    return int(m.body_mocapid[bid])


def check_mujoco_work(n_commands: int, seconds_per_command: float, timestep: float) -> None:
    """Refuse a run of more than :data:`~pushplan.limits.MAX_MUJOCO_STEPS` MuJoCo steps
    (``n_commands * seconds_per_command / timestep``) before it starts.

    Raises
    ------
    InputError
        Names the commands, the time per command and the MJCF timestep.
    """
    from ..limits import MAX_MUJOCO_STEPS

    if not (math.isfinite(timestep) and timestep > 0):
        raise InputError(f"the MJCF <option timestep> must be > 0 and finite, got {timestep}")
    steps = n_commands * seconds_per_command / timestep
    if not steps <= MAX_MUJOCO_STEPS:
        raise InputError(f"{n_commands} commands of {seconds_per_command:g} s at the MuJoCo timestep {timestep:g} s "
                         f"are {steps:.6g} steps, more than {MAX_MUJOCO_STEPS} (a longer timestep, control_period "
                         "or settle_time, or fewer commands)")
