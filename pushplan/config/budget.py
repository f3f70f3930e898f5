"""Memory budget: the memory a mesh needs, estimated from its size before anything is
allocated, against the memory available (``MemAvailable``, the cgroup limit).

The estimate follows what :mod:`fe_contact` stores for a block of ``nx x ny x nz`` hex8
elements, ``n = (nx+1)(ny+1)(nz+1)`` nodes, ``m = 3 (nx+1)(ny+1)`` contact dofs and
``g = nx ny nz q^3`` Gauss points (bytes)::

    W, the local Newton matrix, a step's copy, the root front    4 * 8 m^2
    factor below the root (nested dissection: each of the 3n      8 * 3n * s
      dofs couples to at most one separator of s dofs,
      s = 3 (nz+1)(min(nx, ny)+1) the smallest cross-section)
    assembly (scatter map and element matrices)                   9216 * nx ny nz
    sparse stiffness (81 entries a row, value and index)          12 * 81 * 3n
    kinematics at the Gauss points                                2048 * g
    the interpreter and its libraries                             0.25 GB

The dense terms dominate large meshes: ``[100, 100, 4]`` needs about 35 GB, mostly
``W`` (30603 contact dofs).  Measured peak RSS of ``simulate --no-recording`` (2 steps,
quadrature 2): ``[16, 16, 4]`` 0.26 GB (estimate 0.31 GB), ``[32, 32, 4]`` 0.71 GB
(estimate 0.78 GB).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputError

OVERRIDE_ENV = "PUSHPLAN_NO_MEMORY_CHECK"
"""Set to ``1`` by ``--no-memory-check`` for the run (and its worker processes): every
model is built without the check."""
GB = 1e9
BASELINE = 0.25 * GB
"""The interpreter and its libraries (numpy, scipy, fe_contact, rerun) before a model."""


def estimate_memory(elements, quadrature: int = 2) -> float:
    """Estimated peak memory (bytes) of a model, its factor and ``W``."""
    nx, ny, nz = (int(v) for v in elements)
    n = (nx + 1) * (ny + 1) * (nz + 1)
    m = 3 * (nx + 1) * (ny + 1)
    separator = 3 * (nz + 1) * (min(nx, ny) + 1)
    e = nx * ny * nz
    return float(BASELINE + 4 * 8 * m**2 + 8 * 3 * n * separator + 9216 * e + 12 * 81 * 3 * n
                 + 2048 * e * quadrature**3)


def _meminfo_available() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_available() -> float | None:
    """Limit minus usage of this process's cgroup (v2), None without a limit."""
    try:
        rel = Path("/proc/self/cgroup").read_text().strip().splitlines()[0].split("::", 1)[1]
        folder = Path("/sys/fs/cgroup") / rel.lstrip("/")
        limit = (folder / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return float(limit) - float((folder / "memory.current").read_text())
    except (OSError, ValueError, IndexError):
        return None


def available_memory() -> float | None:
    """Bytes this process may still allocate (the smaller of ``MemAvailable`` and the
    cgroup's room), None where neither is known."""
    known = [v for v in (_meminfo_available(), _cgroup_available()) if v is not None]
    return min(known) if known else None


def check_memory(elements, quadrature: int = 2, copies: int = 1, override: bool | None = None,
                 what: str = "block.elements") -> float:
    """Refuse a mesh whose estimated memory exceeds the available memory.

    Parameters
    ----------
    elements : (3,) ints
    quadrature : int
    copies : int
        Models in memory at once (a sweep's parallel workers).
    override : bool or None
        Only return the estimate (``--no-memory-check``); None: as :data:`OVERRIDE_ENV` says.
    what : str
        The key named in the message.

    Returns
    -------
    float
        The estimate, bytes.

    Raises
    ------
    InputError
        The estimate exceeds the available memory (names both, and the flag).
    """
    if override is None:
        override = os.environ.get(OVERRIDE_ENV) == "1"
    need = copies * estimate_memory(elements, quadrature)
    limit = available_memory()
    if not override and limit is not None and need > limit:
        times = f" x {copies} workers" if copies > 1 else ""
        raise InputError(f"{what} {list(elements)}{times}: estimated memory {need / GB:.3g} GB exceeds the "
                         f"available {limit / GB:.3g} GB (--no-memory-check to run anyway)")
    return need

