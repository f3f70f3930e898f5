"""The one atomic writer: every output file is written under a temporary name in its
own folder and renamed into place, so a reader never sees a half-written file and a
failed write leaves the old one.  Files get the mode the user's umask gives (0644
under umask 022), like any file the user creates."""

from __future__ import annotations

import io
import json
import math
import os
import secrets
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import InputError

TEMP_SUFFIX = ".tmp"


def reserve_temporary(path) -> Path:
    """Create an empty temporary sibling of ``path`` (``.NAME.XXXX.tmp``, mode from the
    umask) and return it; the caller writes it and renames it with :func:`os.replace`."""
    path = Path(path)
    while True:
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}{TEMP_SUFFIX}"
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return tmp
        except FileExistsError:
            continue


def commit_temporary(tmp, path) -> Path:
    """Move a finished temporary (from :func:`reserve_temporary`) into place."""
    os.replace(tmp, path)
    return Path(path)


@contextmanager
def atomic_path(path):
    """A temporary sibling of ``path`` to write (for writers that take a path only):
    moved into place when the block ends, removed if it raises."""
    tmp = reserve_temporary(path)
    try:
        yield tmp
        commit_temporary(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _finite_only(obj):
    """``obj`` with NaN and infinities replaced by None (strict JSON has no such numbers)."""
    if isinstance(obj, dict):
        return {k: _finite_only(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_only(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite_only(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


def json_bytes(obj) -> bytes:
    """``obj`` (numpy arrays allowed) as indented strict JSON; NaN and infinities as ``null``."""
    try:
        text = json.dumps(obj, indent=2, default=_json_default, allow_nan=False)
    except ValueError:
        text = json.dumps(_finite_only(obj), indent=2, default=_json_default, allow_nan=False)
    return (text + "\n").encode()


def atomic_write_json(path, obj) -> Path:
    """:func:`json_bytes` of ``obj`` written atomically."""
    return atomic_write_bytes(path, json_bytes(obj))


def atomic_write_npz(path, **arrays) -> Path:
    """``np.savez_compressed`` atomically, at zlib level 1 (numpy's is 6): the same
    ``.npz`` for ``np.load``, 2 % larger, written in 60 % of the time (paper case 3's
    ``fields.npz``: 447 against 437 kB, 8.9 against 14.4 ms)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, value in arrays.items():  # as numpy.lib.npyio._savez writes them
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    return atomic_write_bytes(path, buf.getvalue())


def prepare_output_dir(path) -> Path:
    """Create the output folder if needed and check it is writable.

    Raises
    ------
    InputError
        The path exists and is not a folder, or cannot be created or written.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"output path exists and is not a folder: {path}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {path}: {exc.strerror}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"output folder is not writable: {path}")
    return path
