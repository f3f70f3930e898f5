"""Output folders as transactions: a run writes into a temporary sibling folder that
replaces ``--out`` in one step at the end, under a lock on ``--out``.

A reader of ``--out`` therefore sees the previous complete output or the new complete
one, never a mix: a run killed (even by ``kill -9``), failing on a full disk or on bad
input leaves the previous output as it was.  The swap is one ``renameat2(...,
RENAME_EXCHANGE)`` on Linux; where the file system refuses it, the old folder is
renamed aside first and a run that dies between the two renames is repaired by the
next run (the finished folder is put in place).

Files of ``--out`` that the command does not write (a plan.json the user keeps there,
a sweep's ``levels/``) are carried into the new folder as hard links (cheap, and safe
because every writer replaces files by renaming, never in place).  The files the
command owns (:class:`OutputTransaction` ``owned``) are not: a run without a recording
does not keep the previous run's ``recording.rrd`` beside its own summary.

Sibling names, in the parent of ``--out`` (``NAME`` its name)::

    .NAME.lock              held (flock) for the whole run, removed at the end
    .NAME.XXXXXXXX.partial  the folder being written
    .NAME.XXXXXXXX.ready    finished, about to be swapped in
    .NAME.XXXXXXXX.old      the previous output, about to be removed

A run that takes the lock removes the stale ones left by killed runs, and the hidden
``.FILE.XXXXXXXX.tmp`` files of :mod:`pushplan.outputs.atomic` inside ``--out``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import fnmatch
import os
import re
import secrets
import shutil
from pathlib import Path

from ..errors import InputError, OutputFailure
from .atomic import TEMP_SUFFIX

STAGES = ("partial", "ready", "old")
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_FULL = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
         errno.EFBIG: "file too large", errno.EROFS: "read-only file system"}


MAX_NAME_BYTES = 255 - len(".." + "0" * 8 + ".partial")
"""Longest output name: its hidden siblings (``.NAME.XXXXXXXX.partial``, ``.NAME.lock``,
``.NAME.XXXXXXXX.tmp``) must fit the file system's 255-byte names."""
MAX_PATH_BYTES = 4096 - 300
"""Longest output path (``PATH_MAX`` 4096, with room for the sibling suffixes and the
files written inside it, ``/.NAME.XXXXXXXX.tmp``: 300 bytes)."""


def check_output_path(path, what: str = "--out", folder: bool = True) -> Path:
    """The absolute output path, refused with one line (:class:`InputError`) when it
    cannot be written as a transaction: a symbolic link (dangling or not: the swap
    would replace the link, not its target), a name too long for its siblings
    (:data:`MAX_NAME_BYTES`), a read-only target (no owner write bit, or no access),
    a file where a folder goes or the reverse, and (``folder`` False: an output file)
    a parent folder that does not exist or cannot be written."""
    raw = Path(path)
    out = Path(os.path.abspath(raw))
    if os.path.islink(raw) or os.path.islink(out):
        target = os.readlink(out)
        state = "" if out.exists() else ", dangling"
        raise InputError(f"{what} {raw} is a symbolic link (to {target}{state}): give the real path")
    if len(os.fsencode(out.name)) > MAX_NAME_BYTES:
        raise InputError(f"{what}: the name {out.name[:40]}... ({len(os.fsencode(out.name))} bytes) is too long "
                         f"(at most {MAX_NAME_BYTES} bytes)")
    if len(os.fsencode(out)) > MAX_PATH_BYTES:
        raise InputError(f"{what}: the path {str(out)[:40]}... ({len(os.fsencode(out))} bytes) is too long "
                         f"(at most {MAX_PATH_BYTES} bytes)")
    if out.exists():
        if folder and not out.is_dir():
            raise InputError(f"{what}: output path exists and is not a folder: {out}")
        if not folder and out.is_dir():
            raise InputError(f"{what} {out} is a folder, not a file")
        if not (os.stat(out).st_mode & 0o200) or not os.access(out, os.W_OK):
            raise InputError(f"{what} {out} is read-only: make it writable or choose another path")
    if not folder:
        parent = out.parent
        if not parent.is_dir():
            raise InputError(f"{what} {out}: the folder {parent} does not exist")
        if not os.access(parent, os.W_OK | os.X_OK) or not (os.stat(parent).st_mode & 0o200):
            raise InputError(f"{what} {out}: cannot write the folder {parent}")
    return out


def output_failure(exc: OSError, where) -> OutputFailure | None:
    """The :class:`OutputFailure` for a full disk, quota or read-only file system, else None."""
    reason = _FULL.get(exc.errno)
    return None if reason is None else OutputFailure(f"cannot write {where}: {reason}")


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2``); False where unsupported."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    libc = ctypes.CDLL(libc_name, use_errno=True)
    if not hasattr(libc, "renameat2"):
        return False
    rc = libc.renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _link_tree(src: Path, dst: Path, skip: tuple = ()) -> None:
    """Hard-link the files of ``src`` missing from ``dst`` (folders recreated), except
    the top-level names matching a pattern of ``skip`` and the temporaries of killed
    writers."""
    for entry in os.scandir(src):
        if any(fnmatch.fnmatchcase(entry.name, pattern) for pattern in skip) or _is_temporary(entry.name):
            continue
        target = dst / entry.name
        if entry.is_dir(follow_symlinks=False):
            target.mkdir(exist_ok=True)
            _link_tree(Path(entry.path), target)
        elif not os.path.lexists(target):
            try:
                os.link(entry.path, target, follow_symlinks=False)
            except OSError as exc:  # a file system without hard links: copy
                if exc.errno not in (errno.EPERM, errno.EXDEV, errno.ENOTSUP, errno.EMLINK):
                    raise
                shutil.copy2(entry.path, target, follow_symlinks=False)


_TMP = re.compile(r"^\..+\.[0-9a-f]{8}" + re.escape(TEMP_SUFFIX) + "$")


def _is_temporary(name: str) -> bool:
    return bool(_TMP.match(name))


def remove_temporaries(folder: Path) -> list[Path]:
    """Remove the ``.FILE.XXXXXXXX.tmp`` files of killed writers under ``folder``."""
    removed = []
    for root, _dirs, files in os.walk(folder):
        for name in files:
            if _is_temporary(name):
                path = Path(root) / name
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed


_STALE = re.compile(rf"^\.(?P<name>.+)\.[0-9a-f]{{8}}\.(?P<stage>{'|'.join(STAGES)})$")


def recover_siblings(parent: Path, name: str | None = None) -> None:
    """Repair what killed transactions left in ``parent`` (for the folder ``name`` only,
    or for all): a folder whose swap was cut short is put in place (the finished new
    one, else the previous one), the other leftovers removed, and the temporaries of
    killed writers inside the folder too.  Call it holding the folder's lock."""
    stale: dict[str, dict[str, list[Path]]] = {}
    for entry in os.scandir(parent):
        m = _STALE.match(entry.name)
        if m and (name is None or m.group("name") == name):
            stale.setdefault(m.group("name"), {s: [] for s in STAGES})[m.group("stage")].append(Path(entry.path))
    for folder, stages in stale.items():
        target = parent / folder
        if not target.exists():
            for candidate in (*stages["ready"], *stages["old"]):  # the new complete output, else the old one
                os.rename(candidate, target)
                break
        for paths in stages.values():
            for path in paths:
                if path.exists():
                    shutil.rmtree(path, ignore_errors=True)
    if name is not None and (parent / name).is_dir():
        remove_temporaries(parent / name)


class OutputLock:
    """An exclusive lock on an output folder (``.NAME.lock`` beside it, ``flock``; the
    kernel drops it when the process dies, so a killed run never leaves a stale lock)."""

    def __init__(self, out: Path):
        self.out = out
        self.path = out.parent / f".{out.name}.lock"
        self.fd = None

    def acquire(self) -> None:
        while True:
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_RDWR, 0o666)
            except OSError as exc:
                raise InputError(f"cannot create the lock {self.path}: {exc.strerror}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise InputError(f"output folder {self.out} is in use by another pushplan run "
                                 f"(lock {self.path}); wait for it or choose another --out") from None
            try:  # the holder before us may have removed the file after we opened it
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self.fd = fd
                return
            os.close(fd)

    def release(self) -> None:
        if self.fd is not None:
            self.path.unlink(missing_ok=True)
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> "OutputLock":
        self.acquire()
        return self

    def __exit__(self, *exc) -> bool:
        self.release()
        return False


def output_file_lock(path, what: str) -> OutputLock:
    """``with output_file_lock(path, "--figure"):`` a single output file (written with
    :mod:`pushplan.outputs.atomic`) checked like ``--out`` (:func:`check_output_path`)
    and locked for the run: a second run onto it refuses at once."""
    return OutputLock(check_output_path(path, what, folder=False))


class OutputTransaction:
    """Write a command's output folder as one transaction.

    Use :func:`output_transaction`; ``path`` is the folder to write, ``out`` the
    final one.

    Parameters
    ----------
    out : path
        The ``--out`` folder (created or replaced at commit).
    owned : iterable of str, or None
        Top-level names (or ``fnmatch`` patterns) the command writes; the previous
        output's files of these names are dropped, every other file is carried
        over.  None: the command owns the whole folder, nothing is carried over.
    lock : bool
        Take the lock on ``out`` (False for a folder inside one already locked,
        such as a sweep's case folders).
    """

    def __init__(self, out, owned=(), lock: bool = True, what: str = "--out"):
        out = check_output_path(out, what)
        cwd = Path.cwd().resolve()
        if out.exists() and (out.resolve() == cwd or out.resolve() in cwd.parents):
            raise InputError(f"--out {out} is the current folder or holds it: the output folder is replaced "
                             "as a whole at the end, choose a folder below the current one")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"cannot create output folder {out}: {exc.strerror}") from None
        if not os.access(out.parent, os.W_OK | os.X_OK):
            raise InputError(f"cannot write the output folder's parent {out.parent}")
        self.out = out
        self.owned = None if owned is None else tuple(owned)
        self.lock = OutputLock(out) if lock else None
        self.path: Path | None = None

    def _sibling(self, token: str, stage: str) -> Path:
        return self.out.parent / f".{self.out.name}.{token}.{stage}"

    def begin(self) -> Path:
        if self.lock is not None:
            self.lock.acquire()
        try:
            if self.lock is not None:  # without it, the caller holding the folder's lock recovers
                recover_siblings(self.out.parent, self.out.name)
            self.token = secrets.token_hex(4)
            self.path = self._sibling(self.token, "partial")
            self.path.mkdir()
        except BaseException:
            self._release()
            raise
        return self.path

    def _release(self) -> None:
        if self.lock is not None:
            self.lock.release()

    def commit(self) -> Path:
        """Carry the files not owned over, then swap the new folder in."""
        if self.out.is_dir() and self.owned is not None:
            _link_tree(self.out, self.path, self.owned)
        ready = self._sibling(self.token, "ready")
        os.rename(self.path, ready)
        self.path = ready
        if not self.out.exists():
            os.rename(ready, self.out)
        elif _exchange(ready, self.out):
            shutil.rmtree(ready, ignore_errors=True)  # now the previous output
        else:
            old = self._sibling(self.token, "old")
            os.rename(self.out, old)
            os.rename(ready, self.out)
            shutil.rmtree(old, ignore_errors=True)
        self.path = None
        return self.out

    def abort(self) -> None:
        if self.path is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            self.path = None

    def __enter__(self) -> "OutputTransaction":
        self.begin()
        return self

    def _named(self, filename) -> Path:
        """The output file a failed write was for, as it would have been named in
        ``out`` (``out/recording.rrd``), else ``out`` itself."""
        try:
            return self.out / Path(os.fsdecode(filename)).resolve().relative_to(Path(self.path).resolve())
        except (TypeError, ValueError, OSError):
            return self.out

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                try:
                    self.commit()
                except OSError as err:
                    self.abort()
                    failure = output_failure(err, self.out)
                    if failure is None:
                        raise
                    raise failure from None
            else:
                where = self._named(getattr(exc, "filename", None))  # before abort() forgets the folder
                self.abort()
                if isinstance(exc, OSError) and not isinstance(exc, OutputFailure):
                    failure = output_failure(exc, where)
                    if failure is not None:
                        raise failure from None
        finally:
            self._release()
        return False


def output_transaction(out, owned=(), lock: bool = True, what: str = "--out") -> OutputTransaction:
    """``with output_transaction(args.out, owned) as tx:`` write into ``tx.path``;
    ``tx.out`` holds the result when the block ends without an exception.

    Raises
    ------
    InputError
        ``out`` is a file, cannot be created, or another run holds its lock.
    OutputFailure
        The disk filled up (or a quota, or a read-only file system) while writing;
        the previous output is left as it was.
    """
    return OutputTransaction(out, owned, lock, what)
