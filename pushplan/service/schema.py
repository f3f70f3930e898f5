"""The service's wire schema (docs/service.md): every request field of every method, its
JSON type and unit, checked by the server before a request reaches a session; and the
encoding of arrays that may hold NaN into strict JSON.

A request is refused (:class:`~pushplan.errors.InputError`, ``INVALID_ARGUMENT``) with one
line naming the field and its value: a field the method does not have, a field of the
wrong type (``"verify": "no"`` is not a boolean), a number that is not finite, a pose or
command row that is not 3 finite numbers.  ``null`` is an optional field left out.
Units: SI and radians (m, rad, N, s).
"""

from __future__ import annotations

import json
import math

import numpy as np

from ..errors import InputError

BOOL, TEXT, SESSION, NUMBER, POSITIVE, POSE, ROWS, FORCE, MESH = (
    "true or false", "a string", "a session id string (Open's \"session\", e.g. \"s1\")",
    "a finite number", "a positive finite number", "[x, y, yaw]: 3 finite numbers (m, m, rad)",
    "a list of rows [dx, dy, dtheta], each 3 finite numbers (m, m, rad)",
    "a finite number or a list of finite numbers (N)", "\"planning\" or \"verification\"")
"""The field types, as a refusal states them."""

_SESSION = {"session": SESSION}
_AIM = {"target": POSE, "tolerance": POSITIVE}
FIELDS = {
    "Open": {"scenario_toml": TEXT, "scenario_path": TEXT, "name": TEXT, "verify": BOOL},
    "Plan": _SESSION | _AIM | {"baseline": BOOL},
    "Replan": _SESSION | {"executed": ROWS, "observed": POSE, "force": FORCE, "time": NUMBER} | _AIM
    | {"closed_loop": BOOL},
    "Rollout": _SESSION | {"commands": ROWS, "jacobian": BOOL, "mesh": MESH, "release": BOOL},
    "Info": _SESSION,
    "Close": _SESSION,
}
"""Method -> {field: type}.  Units: ``target``, ``observed`` m, m, rad; ``tolerance`` m;
``executed``, ``commands`` m, m, rad; ``force`` N; ``time`` s."""
REQUIRED = {"Plan": ("session",), "Replan": ("session", "observed"), "Rollout": ("session", "commands"),
            "Close": ("session",)}


def shown(value, limit: int = 80) -> str:
    """``value`` as JSON text (``NaN`` shown as such), cut to ``limit`` characters."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _row(v) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_number(x) for x in v)


_VALID = {
    BOOL: lambda v: isinstance(v, bool),
    TEXT: lambda v: isinstance(v, str),
    SESSION: lambda v: isinstance(v, str),
    NUMBER: _number,
    POSITIVE: lambda v: _number(v) and v > 0,
    POSE: _row,
    ROWS: lambda v: isinstance(v, list) and all(_row(r) for r in v),
    FORCE: lambda v: _number(v) or (isinstance(v, list) and 0 < len(v) <= 6 and all(_number(x) for x in v)),
    MESH: lambda v: v in ("planning", "verification"),
}


def check(method: str, request: dict) -> None:
    """Refuse a ``method`` request with an unknown field, a field of the wrong type or a
    required field missing: InputError naming the field and its value."""
    fields = FIELDS[method]
    for key, value in request.items():
        if key not in fields:
            raise InputError(f"{shown(key)}: not a field of {method} (its fields: {', '.join(fields)})")
        if value is not None and not _VALID[fields[key]](value):
            raise InputError(f"{key}: expected {fields[key]}, got {shown(value)}")
    for key in REQUIRED.get(method, ()):
        if request.get(key) is None:
            raise InputError(f"{key}: required by {method} ({fields[key]}), got {shown(request.get(key))}")


def rows(value, key: str, max_rows: int = 10_000) -> np.ndarray:
    """``value`` (rows of 3 finite numbers; ``[]`` or None: none) as an (n, 3) float array;
    InputError naming ``key`` and the value otherwise."""
    value = [] if value is None else value
    if not _VALID[ROWS](value):
        raise InputError(f"{key}: expected {ROWS}, got {shown(value)}")
    if len(value) > max_rows:
        raise InputError(f"{key}: at most {max_rows} rows, got {len(value)}")
    return np.array(value, dtype=float).reshape(-1, 3)


def pose(value, key: str) -> np.ndarray:
    """``value`` ([x, y, yaw], 3 finite numbers) as a (3,) float array; InputError otherwise."""
    if not _row(value):
        raise InputError(f"{key}: expected {POSE}, got {shown(value)}")
    return np.array(value, dtype=float)


def nullable(array) -> list:
    """``array`` as nested lists with ``None`` (JSON ``null``) where an entry is not finite:
    strict JSON, which has no NaN (a derivative that does not exist)."""
    a = np.asarray(array, dtype=float)
    return np.where(np.isfinite(a), a.astype(object), None).tolist()


def strict_json(answer: dict) -> bytes:
    """The answer as strict JSON bytes (no NaN or Infinity token).

    Raises
    ------
    ValueError
        A non-finite number is left in ``answer`` (a bug: arrays that may hold NaN go
        through :func:`nullable`).
    """
    return json.dumps(answer, allow_nan=False).encode()
