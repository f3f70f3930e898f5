"""Where a sweep's cases run: a local process pool or a Dask cluster.

Local pool (``spawn`` processes, one BLAS thread each):

- workers die with their parent: each watches its parent process and exits within
  :data:`PARENT_POLL_S` once it is gone (``kill -9`` or SIGTERM of the sweep included);
- workers ignore SIGINT: a Ctrl-C reaches the sweep, which kills its workers and
  stops (the finished cases are kept, a rerun resumes);
- a worker that dies (killed, out of memory) breaks the pool: the cases it took down
  run again in a new pool, up to :data:`MAX_ATTEMPTS` times each.

Dask: the connection to ``--scheduler`` (TCP connect and Dask handshake) must finish
within :data:`SCHEDULER_TIMEOUT_S`; a peer that does not speak Dask is one line.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import struct
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Callable

from ..errors import InputError

SCHEDULER_TIMEOUT_S = 10
PARENT_POLL_S = 0.5
MAX_ATTEMPTS = 3
"""Runs of a case whose worker died before it is recorded as an error."""
THREAD_VARIABLES = {"OPENBLAS_NUM_THREADS": "blas", "OMP_NUM_THREADS": "openmp", "MKL_NUM_THREADS": None,
                    "FE_CONTACT_DENSE_THREADS": None}
"""Environment variables set to 1 in the case processes -> the threadpoolctl ``user_api``
also limited to one thread there (libraries loaded before the variable was set)."""


def worker_environment() -> dict:
    """The :data:`THREAD_VARIABLES` the caller's environment does not set, each ``"1"``."""
    return {v: "1" for v in THREAD_VARIABLES if v not in os.environ}


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # the sweep is gone: nobody will read this case's result


def single_threaded(environment: dict, parent: int | None = None) -> None:
    """Pool initializer, in the worker process: set ``environment`` there and limit
    the thread pools of the libraries loaded (numpy's BLAS is loaded first);
    with ``parent`` (the sweep's pid), exit when that process is gone and leave SIGINT
    to it."""
    import numpy  # noqa: F401 - load BLAS now, so that the limit below reaches it
    from threadpoolctl import threadpool_limits

    os.environ.update(environment)
    limits = {THREAD_VARIABLES[v]: 1 for v in environment if THREAD_VARIABLES.get(v)}
    if limits:
        threadpool_limits(limits=limits)
    if parent is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="pushplan-parent-watch").start()


def executor_error(exc: BaseException, note: str = "") -> dict:
    """A case's outcome when the executor, not the case, failed."""
    return {"files": {}, "error": " ".join(f"{type(exc).__name__}: {exc}{note}".split()), "traceback": None}


def _kill(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now: its workers killed, queued cases cancelled."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):  # no public handle on the workers
        process.kill()
    pool.shutdown(wait=False, cancel_futures=True)


def run_local(run_case: Callable, tasks: list[dict], workers: int, on_result: Callable) -> None:
    """Run ``run_case(task)`` for every task on a pool of ``workers`` processes,
    ``on_result(task, outcome)`` as each finishes (in the calling process)."""
    import multiprocessing

    # spawn: safe with the threads of fe_contact and of an in-process Dask cluster
    ctx = multiprocessing.get_context("spawn")
    attempts = {id(t): 0 for t in tasks}
    pending = list(tasks)
    while pending:
        broken = []
        pool = ProcessPoolExecutor(max_workers=min(workers, len(pending)), mp_context=ctx,
                                   initializer=single_threaded, initargs=(worker_environment(), os.getpid()))
        try:
            futures = {pool.submit(run_case, t): t for t in pending}
            for fut in as_completed(futures):
                task = futures[fut]
                try:
                    outcome = fut.result()
                except BrokenProcessPool as exc:  # a worker died: its cases run again in a new pool
                    attempts[id(task)] += 1
                    if attempts[id(task)] < MAX_ATTEMPTS:
                        broken.append(task)
                        continue
                    outcome = executor_error(exc, f" (a worker died on each of {MAX_ATTEMPTS} attempts)")
                except Exception as exc:  # e.g. MemoryError unpickling: record, go on
                    outcome = executor_error(exc)
                on_result(task, outcome)
        except BaseException:  # interrupted, or storing a result failed: stop the workers now
            _kill(pool)
            raise
        pool.shutdown(wait=True)
        pending = broken


def run_dask(run_case: Callable, tasks: list[dict], client, on_result: Callable) -> None:
    from dask.distributed import as_completed as dask_completed

    futures = {client.submit(run_case, t, pure=False): t for t in tasks}
    for fut in dask_completed(list(futures)):
        try:
            outcome = fut.result()
        except Exception as exc:  # KilledWorker, lost connection: record, go on
            outcome = executor_error(exc)
        on_result(futures[fut], outcome)


_TCP_ADDRESS = re.compile(r"^(?:tcp://)?(?P<host>\[[^\]]+\]|[^:/\[\]]+):(?P<port>\d{1,5})/?$")
MAX_HANDSHAKE_BYTES = 2**20
"""Largest first message accepted from a scheduler (a Dask handshake is ~100 bytes)."""


def _probe(scheduler: str, timeout: float) -> None:
    """For a TCP address: connect and read the first 8 bytes of the handshake a Dask
    server sends on accepting (its length, uint64), within ``timeout`` in all.  A silent
    peer, or one whose first bytes are no plausible Dask length (an HTTP server), is
    refused here, before Dask waits forever or allocates that length."""
    m = _TCP_ADDRESS.match(scheduler)
    if m is None:  # tls://, inproc://, ...: left to Dask and the deadline of connect()
        return
    host, port = m.group("host").strip("[]"), int(m.group("port"))
    deadline = time.monotonic() + timeout
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            head = b""
            while len(head) < 8:
                sock.settimeout(max(deadline - time.monotonic(), 0.01))
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    raise InputError(f"--scheduler {scheduler!r}: the peer closed the connection without "
                                     "a Dask handshake")
                head += chunk
    except TimeoutError:
        raise InputError(f"--scheduler {scheduler!r}: no Dask scheduler answered within {timeout:g} s") from None
    except OSError as exc:
        raise InputError(f"--scheduler {scheduler!r}: cannot connect ({exc.strerror or exc})") from None
    if not 0 < struct.unpack("<Q", head)[0] <= MAX_HANDSHAKE_BYTES:
        raise InputError(f"--scheduler {scheduler!r}: the peer does not speak the Dask protocol "
                         f"(its first bytes are {head!r})")


def connect(scheduler: str, timeout: float = SCHEDULER_TIMEOUT_S):
    """A ``dask.distributed.Client`` of the scheduler at ``scheduler``, connected and
    past the Dask handshake within ``timeout`` seconds.

    Raises
    ------
    InputError
        No answer in time, a refused or bad address, or a peer that is not a Dask
        scheduler (one line naming the address).
    """
    _probe(scheduler, timeout)  # before importing dask (seconds)
    from dask.distributed import Client

    box: dict = {}

    def attempt():
        try:
            box["client"] = Client(scheduler, timeout=timeout)
        except MemoryError:  # an HTTP (or other) server's answer read as a Dask frame length
            box["error"] = "the peer does not speak the Dask protocol"
        except (OSError, ValueError, TypeError) as exc:  # what Client raises for a bad or unreachable address
            box["error"] = f"cannot connect ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})"
        except Exception as exc:  # a peer sending a plausible length, then garbage: any decoding error
            box["error"] = (f"the peer does not speak the Dask protocol ({type(exc).__name__}: "
                            f"{' '.join(str(exc).split())[:200]})")

    thread = threading.Thread(target=attempt, daemon=True, name="pushplan-dask-connect")
    thread.start()
    thread.join(timeout + 2.0)
    if thread.is_alive():
        raise InputError(f"--scheduler {scheduler!r}: no Dask scheduler answered within {timeout:g} s")
    if "client" not in box:
        raise InputError(f"--scheduler {scheduler!r}: {box.get('error', 'no Dask client')}")
    return box["client"]
