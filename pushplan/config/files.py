"""Reading input files (TOML, JSON) into dicts, with one-line errors naming the file.

Before a file is parsed: it must be a regular file (not ``/dev/zero``, a FIFO or a
folder) of at most :data:`MAX_INPUT_BYTES`, with brackets nested at most
:data:`MAX_NESTING` deep and dotted keys of at most :data:`MAX_KEY_PARTS` parts, so
that a small hostile file cannot make the parser recurse or allocate without bound
(a 40 kB dotted TOML key costs ``tomllib`` gigabytes).
"""

from __future__ import annotations

import json
import os
import re
import stat
import tomllib
from pathlib import Path

from ..errors import InputError

MAX_INPUT_BYTES = 4 * 2**20
"""Largest input file read (4 MiB): scenario, sweep and command files are a few kB."""
MAX_NESTING = 32
"""Deepest nesting of arrays / tables (``[`` and ``{``) in an input file."""
MAX_KEY_PARTS = 16
"""Most parts of a dotted TOML key (``a.b.c`` has 3)."""

# tokens that matter for nesting, strings and comments skipped whole
_TOML_TOKENS = re.compile(
    r'"""(?:[^"\\]|\\.|"(?!""))*"""|\'\'\'.*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}.=,\n]',
    re.S)
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise InputError(f"cannot read {what} file {path}: {kind}")
    if info.st_size > MAX_INPUT_BYTES:
        raise InputError(f"{what} file {path} is larger than {MAX_INPUT_BYTES} bytes")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_INPUT_BYTES + 1)
    except OSError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc.strerror}") from None
    if len(data) > MAX_INPUT_BYTES:
        raise InputError(f"{what} file {path} is larger than {MAX_INPUT_BYTES} bytes")
    return data


def _decode(data: bytes, path: Path, what: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"malformed {what} file {path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None


def check_nesting(text: str, path, what: str, toml: bool = True) -> None:
    """Refuse nesting deeper than :data:`MAX_NESTING` or (TOML) dotted keys of more
    than :data:`MAX_KEY_PARTS` parts, scanning tokens outside strings and comments."""
    depth = dots = 0
    for m in (_TOML_TOKENS if toml else _JSON_TOKENS).finditer(text):
        token = m.group()
        if token in "[{":
            depth += 1
            if depth > MAX_NESTING:
                line = text.count("\n", 0, m.start()) + 1
                raise InputError(f"cannot read {what} file {path}: nesting deeper than {MAX_NESTING} levels "
                                 f"at line {line}")
        elif token in "]}":
            depth -= 1
        if token == ".":
            dots += 1
            if dots >= MAX_KEY_PARTS:
                line = text.count("\n", 0, m.start()) + 1
                raise InputError(f"cannot read {what} file {path}: a dotted key of more than {MAX_KEY_PARTS} "
                                 f"parts at line {line}")
        elif len(token) == 1 and token in "[]{}=,\n":
            dots = 0


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= 200 else text[:200] + "..."


def read_toml(path, what: str = "scenario") -> dict:
    """Parse a TOML file; ``what`` names the file kind in messages."""
    path = Path(path)
    text = _decode(_read_bytes(path, what), path, "TOML")
    check_nesting(text, path, what, toml=True)
    try:
        return tomllib.loads(text)
    except (ValueError, RecursionError) as exc:  # TOMLDecodeError, an integer of over 4300 digits
        raise InputError(f"malformed TOML in {path}: {_one_line(exc)}") from None


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
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read {what} file {path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    check_nesting(text, path, what, toml=False)
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, an integer of over 4300 digits
        raise InputError(f"cannot read {what} file {path}: {_one_line(exc)}") from None
