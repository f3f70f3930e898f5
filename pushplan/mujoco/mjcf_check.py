"""The MJCF files of a scene checked before MuJoCo compiles them: each file (the scene
and every ``<include file>``, recursively) a regular file of at most
:data:`~pushplan.config.files.MAX_INPUT_BYTES` (4 MiB), well-formed XML, and every
numeric attribute finite, every ``friction`` >= 0.  MuJoCo reads an unreadable number
(``nan``) as its default (friction 1) and clamps a negative friction to 1e-5, silently,
wherever the attribute is (a ``<default>`` class, an included file); so the values are
checked as written, each error one line naming the file, element and attribute."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from ..config.files import read_text
from ..errors import InputError

MAX_INCLUDES = 64
"""Most MJCF files of one scene (the scene and its includes)."""
NAME_ATTRIBUTES = {"name", "class", "childclass", "file", "prefix", "body", "body1", "body2", "geom", "geom1",
                   "geom2", "site", "joint", "joint1", "joint2", "target", "material", "texture", "mesh", "hfield",
                   "tendon", "actuator", "objname", "model", "content_type", "meshdir", "texturedir", "assetdir",
                   "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback", "key"}
"""Attributes that name things (a name may read as a number: not checked)."""


def _numbers(text: str) -> list[float] | None:
    """The attribute as a list of floats, None if it is not a numeric list."""
    try:
        return [float(v) for v in text.split()] or None
    except ValueError:
        return None


def _check_element(el: ET.Element, path: Path) -> None:
    for attr, text in el.attrib.items():
        if attr in NAME_ATTRIBUTES:
            continue
        values = _numbers(text)
        if values is None:
            continue
        if not all(math.isfinite(v) for v in values):
            raise InputError(f"MJCF {path}: <{el.tag}{_label(el)}> {attr}={text!r} must be finite "
                             "(MuJoCo would read its default instead)")
        if attr == "friction" and min(values) < 0:
            raise InputError(f"MJCF {path}: <{el.tag}{_label(el)}> friction={text!r} must be >= 0 "
                             "(MuJoCo would clamp it to 1e-5)")


def _label(el: ET.Element) -> str:
    for key in ("name", "class"):
        if key in el.attrib:
            return f" {key}={el.attrib[key]!r}"
    return ""


def check_mjcf(path) -> None:
    """Check the MJCF scene ``path`` and its includes (see the module docstring).

    Raises
    ------
    InputError
        A file missing, special, over 4 MiB or not XML; a non-finite number or a
        negative friction; more than :data:`MAX_INCLUDES` files.
    """
    todo, seen = [Path(path)], set()
    while todo:
        file = todo.pop()
        key = file.resolve()
        if key in seen:
            continue
        seen.add(key)
        if len(seen) > MAX_INCLUDES:
            raise InputError(f"MJCF {path}: more than {MAX_INCLUDES} files (includes)")
        text = read_text(file, "MJCF")
        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            raise InputError(f"MJCF {file} is not well-formed XML: {' '.join(str(exc).split())}") from None
        for el in root.iter():
            _check_element(el, file)
            if el.tag == "include" and "file" in el.attrib:
                # MuJoCo resolves includes relative to the top-level model's folder
                todo.append(Path(path).parent / el.attrib["file"])
