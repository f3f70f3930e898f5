"""The one codec of upper-face commands between ``fe_contact.Command`` (m, rad) and
files (``{"dx": m, "dy": m, "dz": m, "dtheta_deg": deg}``; the ``"open"`` steps of the
removed open release are refused, naming the key), used by scenarios,
``plan.json``, summaries, recordings and the MuJoCo bridge.

A command file is any JSON object with a ``commands`` list (a ``plan.json``),
re-executable with ``pushplan simulate SCENARIO --commands FILE``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fe_contact import Command

from ..errors import InputError
from ..limits import MAX_STEPS
from .files import read_json
from .validate import Table

COMMAND_KEYS = ("dx", "dy", "dz", "dtheta_deg")
RELEASE_KEYS = ("open",)
MAX_TURN_DEG = 180.0
"""Largest turn of one step, exclusive: a rotation is known modulo 360 deg, so a turn of
half a revolution or more in one step would be silently another one (360 deg = none)."""


def degrees_exact(angle: float) -> float:
    """``angle`` (rad) in degrees, chosen among the nearest floats so that
    ``math.radians`` gives ``angle`` back exactly where such a float exists
    (a file written and read again then holds the same command, bit for bit)."""
    d = math.degrees(angle)
    candidate = d
    for _ in range(4):
        if math.radians(candidate) == angle:
            return candidate
        candidate = math.nextafter(candidate, math.inf if math.radians(candidate) < angle else -math.inf)
    return d


def command_to_dict(c: Command) -> dict:
    return {"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": degrees_exact(c.dtheta)}


def command_from_dict(item, key: str) -> Command:
    """A command from its dict; missing components are 0; ``key`` names it in messages."""
    t = Table(item, key, COMMAND_KEYS + RELEASE_KEYS)
    dx, dy, dz = (t.number(k, 0.0) for k in COMMAND_KEYS[:3])
    dtheta_deg = t.number("dtheta_deg", 0.0, lo=-MAX_TURN_DEG, hi=MAX_TURN_DEG)
    if "open" in t:
        raise InputError(f"{t.key('open')}: the open release was removed (its rest pose depended on an assumed pad "
                         "stiffness); let go with [release] mode = \"lift\" and gripper.friction")
    return Command(dx, dy, dz, math.radians(dtheta_deg))


def commands_to_list(commands) -> list[dict]:
    return [command_to_dict(c) for c in commands]


def commands_from_list(items, key: str = "commands") -> tuple[Command, ...]:
    if not isinstance(items, list):
        raise InputError(f"{key} must be a list of commands, got {type(items).__name__}")
    if len(items) > MAX_STEPS:
        raise InputError(f"{key} holds {len(items)} commands, more than {MAX_STEPS}")
    return tuple(command_from_dict(item, f"{key}[{i}]") for i, item in enumerate(items))


PLANAR_COMPONENTS = [0, 1, 3]
"""Where the in-plane increments ``(dx, dy, dtheta)`` of :func:`planar_commands` sit among
a Command's ``(dx, dy, dz, dtheta)`` (the columns of ``fe_contact.rollout_derivatives``)."""


def planar_commands(array) -> tuple[Command, ...]:
    """Commands from an (K, 3) array of in-plane increments ``(dx, dy, dtheta)`` (m, rad)."""
    return tuple(Command(dx=float(c[0]), dy=float(c[1]), dtheta=float(c[2])) for c in np.asarray(array, float))


def load_commands(path) -> tuple[Command, ...]:
    """The ``commands`` list of a JSON file (a ``plan.json``).

    Raises
    ------
    InputError
        Missing or malformed file, no ``commands`` list, or a bad entry (named).
    """
    return read_command_file(path)[0]


def read_command_file(path) -> tuple[tuple[Command, ...], dict]:
    """The ``commands`` of a JSON file and the whole document (for the fingerprint
    of :mod:`pushplan.config.fingerprint`)."""
    path = Path(path)
    data = read_json(path, "commands")
    if not isinstance(data, dict) or "commands" not in data:
        raise InputError(f"{path}: expected an object with a 'commands' list")
    try:
        return commands_from_list(data["commands"]), data
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
