"""A small TOML writer for the tables ``pushplan`` writes (a scenario's ``to_dict()``):
strings, booleans, integers, floats (``repr``: read back exactly by ``tomllib``),
arrays of those, tables and arrays of tables.  ``tomllib.loads(toml_text(d)) == d``."""

from __future__ import annotations

import json
import math


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a JSON string is a TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} to TOML: {v!r}")


def _is_table_array(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _table(data: dict, path: tuple[str, ...], lines: list[str]) -> None:
    for k, v in data.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in data.items():
        name = ".".join(_key(p) for p in (*path, k))
        if isinstance(v, dict):
            lines += ["", f"[{name}]"]
            _table(v, (*path, k), lines)
        elif _is_table_array(v):
            for item in v:
                lines += ["", f"[[{name}]]"]
                _table(item, (*path, k), lines)


def toml_text(data: dict, header: str = "") -> str:
    """``data`` as a TOML document, after ``header`` comment lines (``# `` prefixed)."""
    lines = [f"# {line}" for line in header.splitlines()]
    _table(data, (), lines)
    return "\n".join(lines).lstrip("\n") + "\n"
