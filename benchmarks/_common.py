"""Shared helpers of the benchmark scripts: machine info and JSON output."""

from __future__ import annotations

import json
import os
import platform
import sys
from pathlib import Path

import numpy as np
import scipy

from fe_contact.linalg.threads import dense_threads

RESULTS = Path(__file__).resolve().parent / "results"
NOT_A_USERS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "FE_CONTACT_DENSE_THREADS",
               "PYTHONDONTWRITEBYTECODE")
"""Environment variables a user's shell does not set: the thread limits the Makefile exports, and
PYTHONDONTWRITEBYTECODE (set on some development machines), which makes every process compile
again the modules changed since their bytecode was cached (60 ms of a paper-case simulate)."""


def user_env(**extra) -> dict:
    """The environment of a process started as a user starts it (:data:`NOT_A_USERS` removed),
    with ``extra`` set."""
    return {**{k: v for k, v in os.environ.items() if k not in NOT_A_USERS}, **extra}


def machine_info() -> dict:
    """Where the numbers were measured."""
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
        "dense_kernel_threads": dense_threads(),  # BLAS threads of the large dense kernels
    }


def write_results(name: str, payload: dict) -> Path:
    """Write ``benchmarks/results/<name>.json`` (atomically) and return its path."""
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"machine": machine_info(), **payload}, indent=2, default=float))
    os.replace(tmp, path)
    return path
