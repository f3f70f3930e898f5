"""Reading input files (TOML, JSON) into dicts, with one-line errors naming the file."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from ..errors import InputError

MAX_INPUT_BYTES = 4 * 2**20
"""Largest input file read (4 MiB): scenario, sweep and command files are a few kB."""


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_INPUT_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc.strerror}") from None
    if len(data) > MAX_INPUT_BYTES:
        raise InputError(f"{what} file {path} is larger than {MAX_INPUT_BYTES} bytes")
    return data


def read_toml(path, what: str = "scenario") -> dict:
    """Parse a TOML file; ``what`` names the file kind in messages."""
    path = Path(path)
    data = _read_bytes(path, what)
    try:
        return tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"malformed TOML in {path}: {exc}") from None


def read_text(path, what: str) -> str:
    """A UTF-8 text file; ``what`` names the file kind in messages."""
    path = Path(path)
    try:
        return _read_bytes(path, what).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None


def read_json(path, what: str) -> object:
    """Parse a JSON file; ``what`` names the file kind in messages."""
    path = Path(path)
    data = _read_bytes(path, what)
    try:
        return json.loads(data.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(f"cannot read {what} file {path}: {exc}") from None
