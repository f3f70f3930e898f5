"""BLAS threads: one in the package's processes, more only in the large dense kernels.

The multifrontal factorisation of a large tangent (with the flexibility
matrix) and the local Newton LU are dense BLAS-3 work that two threads run
about 1.8x faster (measured: LU of the paper case's 1323 x 1323 Newton
matrix, 62 -> 33 ms); everything else in a step is
small dense or sparse work that threads slow down, so BLAS is best left at one
thread and raised only around these kernels.  On a machine whose cores are
busy, BLAS threads that spin waiting for a core made whole runs 4-7 times
slower (issue 21).  Importing :mod:`fe_contact` therefore limits BLAS to one
thread (:func:`limit_blas_threads`) unless the user set one of
:data:`USER_VARIABLES`, which then rule.

``FE_CONTACT_DENSE_THREADS`` sets the thread count of those kernels; unset, it
is the number of CPUs this process may use that other work leaves idle
(:func:`idle_cpus`): on a loaded machine the second thread waits for a core
and costs more than it saves (paper case 3 at load average 5 on 2 cores:
1.66 / 2.17 s with one thread in the dense kernels, 2.57 / 3.55 s with two,
alternating runs; the tangent 4-5x slower).  Processes that already share
the cores (``pushplan sweep`` workers, parallel test workers) set it to 1.
"""

from __future__ import annotations

import os
from contextlib import nullcontext

from threadpoolctl import ThreadpoolController

ENV = "FE_CONTACT_DENSE_THREADS"
MIN_SIZE = 1000
"""Matrix order from which a second thread pays (measured: 1.2x at 1000, 1.0x at 600)."""

USER_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                  "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
"""Thread variables that OpenBLAS, MKL, BLIS or Accelerate read: if the user set
any of them, the package leaves the BLAS thread count alone."""

_controller: ThreadpoolController | None = None


def _blas_controller() -> ThreadpoolController:
    global _controller
    if _controller is None:
        _controller = ThreadpoolController()
    return _controller


def limit_blas_threads() -> bool:
    """Limit every BLAS loaded in this process to one thread, unless one of
    :data:`USER_VARIABLES` is set; True if it did.

    Called when :mod:`fe_contact` is imported, after NumPy and SciPy (each
    wheel brings its own OpenBLAS) are loaded.  The limit stays for the
    process; :func:`dense_kernel` raises it inside the large dense kernels.
    """
    if any(v in os.environ for v in USER_VARIABLES):
        return False
    _blas_controller().limit(limits=1, user_api="blas")
    return True


def idle_cpus() -> int:
    """The CPUs this process may use less the other work, at least 1: less the
    1-minute load average beyond this process's own 1 (rounded), and less the
    threads of other processes running now (:func:`running_elsewhere`); all of
    them where neither is available.

    The load average lags by about a minute: work that started since (a test
    suite, another run) is seen only by the count of running threads, and with
    it the second thread of a kernel waits for a core (paper case 3 with one
    other CPU-bound process on 2 cores and a load average of 1.1-1.6 that still
    said "2 idle": 1.9-4.7 s wall, 1.7-2.0 s with one thread, alternating runs).
    The load average counts this process's own threads, so a long stretch of
    two-threaded kernels can lower it to one thread: at most the 1.8x of the
    kernels, where a busy machine costs 4x.
    """
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    idle = cpus
    try:
        idle = min(idle, int(cpus - max(os.getloadavg()[0] - 1.0, 0.0) + 0.5))
    except (AttributeError, OSError):
        pass
    others = running_elsewhere()
    if others is not None:
        idle = min(idle, cpus - others)
    return max(1, idle)


def running_elsewhere() -> int | None:
    """Threads of other processes running or runnable now: the running count of
    ``/proc/loadavg`` less this process's own running threads (its BLAS workers
    spin for a while after a threaded kernel; they are not other work); None
    without ``/proc`` (not Linux).  About 0.1 ms: asked once per large dense kernel
    (:func:`dense_kernel`), never for the small ones."""
    try:
        return max(_running_threads() - _own_running_threads(), 0)
    except (OSError, ValueError, IndexError):
        return None


def _running_threads() -> int:
    """Threads running or runnable on the machine now (``/proc/loadavg``, field 4)."""
    with open("/proc/loadavg", "rb") as f:
        return int(f.read().split()[3].split(b"/")[0])


def _own_running_threads() -> int:
    """This process's threads in state R (``/proc/self/task/*/stat``): at least the caller."""
    own = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat", "rb") as f:
                stat = f.read()
        except OSError:  # the thread ended meanwhile
            continue
        state = stat.rindex(b")") + 2  # the state follows the command name, which may hold spaces
        own += stat[state:state + 1] == b"R"
    return own


def dense_threads() -> int:
    """Threads for the large dense kernels (``FE_CONTACT_DENSE_THREADS`` or :func:`idle_cpus`)."""
    value = os.environ.get(ENV)
    if value is None:
        return idle_cpus()
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"{ENV} must be an integer >= 1, got {value!r}")
    return n


def dense_kernel(size: int):
    """Context in which BLAS runs on :func:`dense_threads` threads, for a dense
    kernel of order ``size``; below :data:`MIN_SIZE` it changes nothing (and does
    not look at the machine's load: a plan's small local problems ask 60 times)."""
    if size < MIN_SIZE:
        return nullcontext()
    n = dense_threads()
    if n <= 1:
        return nullcontext()
    return _blas_controller().limit(limits=n, user_api="blas")
