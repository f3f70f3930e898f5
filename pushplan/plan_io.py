"""Command files: the ``commands`` list of a ``plan.json`` (or any JSON file with
one), each ``{"dx": m, "dy": m, "dz": m, "dtheta_deg": deg}``, re-executable with
``pushplan simulate SCENARIO --commands FILE``."""

from __future__ import annotations

import json
import math
from pathlib import Path

from fe_contact import Command


def commands_to_json(commands) -> list[dict]:
    """Commands as JSON-ready dicts (m, degrees)."""
    return [{"dx": c.dx, "dy": c.dy, "dz": c.dz, "dtheta_deg": math.degrees(c.dtheta)} for c in commands]


def load_commands(path) -> list[Command]:
    """Read the ``commands`` list of a JSON file.

    Raises
    ------
    ValueError
        Missing file, malformed JSON, no ``commands`` list, or a bad entry (named).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"commands file not found: {path}") from None
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read commands file {path}: {exc}") from None
    items = data.get("commands") if isinstance(data, dict) else None
    if not isinstance(items, list):
        raise ValueError(f"{path}: expected an object with a 'commands' list")
    out = []
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise ValueError(f"{path}: commands[{i}] must be an object, got {item!r}")
        unknown = set(item) - {"dx", "dy", "dz", "dtheta_deg"}
        if unknown:
            raise ValueError(f"{path}: unknown key commands[{i}].{sorted(unknown)[0]}")
        vals = {}
        for k in ("dx", "dy", "dz", "dtheta_deg"):
            v = item.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{path}: commands[{i}].{k} must be a finite number, got {v!r}")
            vals[k] = float(v)
        out.append(Command(vals["dx"], vals["dy"], vals["dz"], math.radians(vals["dtheta_deg"])))
    return out
