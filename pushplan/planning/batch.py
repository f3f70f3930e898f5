"""Warm worker processes for batches of FE rollouts (issue 40 item 1).

A :class:`RolloutPool` starts ``processes`` workers once; each holds its own
copy of a :class:`~pushplan.planning.push_model.PushModel` (sent when the
worker starts, never again) and the start states it was sent, each with its
factorised tangent (``State.tangent``, reused read-only by the first step of
every rollout branched from it, exactly as a rollout in this process reuses
it).  A batch sends the commands and, the first time a worker meets it, the
start state; later batches from the same state send its key only.  Workers
stay alive between batches until :meth:`RolloutPool.close` (or the end of a
``with`` block, or the pool's collection).

Scheduling is dynamic and guided: the next chunk goes to the first idle worker
and holds ``ceil(r / (2 * processes))`` of the ``r`` rollouts not yet sent, so
chunks shrink to one rollout at the end of a batch: a worker waits for the last
one at most one rollout (fixed chunks of ``n / (4 * processes)``, 4 rollouts of a
batch of 32 on 2 workers, left one worker idle for up to 4 rollouts at the end: up
to 25 % of the batch's wall time), and a rollout that needs more Newton
iterations does not hold the others back.
Every rollout runs the same code on the same inputs as a single call in this
process (the BLAS of each worker on one thread, also when the user's
``OPENBLAS_NUM_THREADS`` gave the calling process more: two workers of two
threads each on two cores would wait for each other), so the numbers are the same
(``tests/test_batch_rollouts.py`` checks them to 1e-12).

Cost: a worker's start costs a fork (about 10 ms) plus, per start state, the
pickled state and its factor through a pipe (about 1 ms per MB); each chunk
costs one message each way (about 0.1 ms).  ``benchmarks/batch_rollouts.py``
measures the throughput.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import weakref
from collections import OrderedDict
from multiprocessing.connection import wait

from ..errors import SolverFailure
from .rollouts import PlanningError

METHODS = {"poses": "rollout", "forces": "rollout_with_forces", "jacobian": "rollout_with_jacobian"}
"""The :class:`PushModel` method a worker runs for each kind of batch."""
STATE_CAP = 8
"""Start states a worker holds at once (the oldest is dropped beyond it)."""


def default_processes() -> int:
    """The CPUs this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _context():
    """Fork where the platform has it (no re-import of the user's script), else spawn."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


def _serve(conn, push) -> None:
    """A worker's loop: hold start states by key, run chunks of rollouts, reply."""
    from threadpoolctl import threadpool_limits

    # the cores are the pool's: one BLAS thread per worker, in the dense kernels too,
    # whatever the user's thread variables gave the calling process
    os.environ["FE_CONTACT_DENSE_THREADS"] = "1"
    threadpool_limits(limits=1, user_api="blas")
    states = {}
    while True:
        try:
            message = conn.recv()
        except EOFError:
            return
        if message is None:
            return
        op, *args = message
        if op == "state":
            key, start = args
            states[key] = start
        elif op == "drop":
            states.pop(args[0], None)
        else:  # "run"
            kind, key, chunk = args
            try:
                conn.send(_run_chunk(push, kind, states[key], chunk))
            except (BrokenPipeError, OSError):  # the pool closed while this chunk ran
                return


def _run_chunk(push, kind: str, start, chunk) -> list:
    """``(index, result or the exception)`` of each ``(index, commands)`` of ``chunk``."""
    run = getattr(push, METHODS[kind])
    out = []
    for index, commands in chunk:
        try:
            out.append((index, run(commands, start=start)))
        except (SolverFailure, ValueError) as exc:  # a rollout's failure is its own, not the batch's
            out.append((index, exc))
    return out


class _Worker:
    def __init__(self, context, push):
        self.conn, child = context.Pipe()
        self.process = context.Process(target=_serve, args=(child, push), daemon=True)
        self.process.start()
        child.close()
        self.keys = OrderedDict()  # the start states this worker holds, oldest first

    def hold(self, key, start) -> None:
        if key in self.keys:
            self.keys.move_to_end(key)
            return
        self.conn.send(("state", key, start))
        self.keys[key] = None
        if len(self.keys) > STATE_CAP:
            self.conn.send(("drop", self.keys.popitem(last=False)[0]))


def _stop(workers) -> None:
    for w in workers:
        try:
            w.conn.send(None)
            w.conn.close()
        except (OSError, BrokenPipeError):
            pass
    for w in workers:
        w.process.join(timeout=1)
        if w.process.is_alive():  # busy with a chunk nobody will read
            w.process.terminate()
            w.process.join()


class _Guided:
    """The chunks of a batch, each ``ceil(remaining / (2 * processes))`` of the
    ``(index, commands)`` pairs not yet handed out (module docstring)."""

    def __init__(self, items: list, processes: int):
        self._items, self._next, self._parts = items, 0, 2 * processes

    def __bool__(self) -> bool:
        return self._next < len(self._items)

    def pop(self) -> list:
        size = math.ceil((len(self._items) - self._next) / self._parts)
        chunk = self._items[self._next:self._next + size]
        self._next += size
        return chunk


class RolloutPool:
    """``processes`` warm workers of one :class:`PushModel` (module docstring).

    Parameters
    ----------
    push : PushModel
    processes : int, optional
        Workers (default: the CPUs this process may use).
    """

    def __init__(self, push, processes: int | None = None):
        processes = default_processes() if processes is None else processes
        if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
            raise ValueError(f"processes must be an integer >= 1, got {processes!r}")
        self.processes = processes
        context = _context()
        self._workers = [_Worker(context, push) for _ in range(processes)]
        self._starts = OrderedDict()  # id(start) -> (key, start): a strong reference keeps the id unique
        self._next_key = 0
        self._finalizer = weakref.finalize(self, _stop, self._workers)

    @property
    def closed(self) -> bool:
        return not self._finalizer.alive

    def close(self) -> None:
        """Stop the workers (idempotent)."""
        self._finalizer()

    def __enter__(self) -> "RolloutPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _key(self, start) -> int:
        entry = self._starts.get(id(start))
        if entry is not None and entry[1] is start:
            self._starts.move_to_end(id(start))
            return entry[0]
        key, self._next_key = self._next_key, self._next_key + 1
        self._starts[id(start)] = (key, start)
        if len(self._starts) > STATE_CAP:  # the workers drop theirs when they pass the same cap
            self._starts.popitem(last=False)
        return key

    def run(self, kind: str, batch, start) -> list:
        """Results of ``kind`` (a key of :data:`METHODS`) for each command array of
        ``batch`` from ``start``, in order.

        Raises
        ------
        PlanningError
            A rollout failed (the first failing one is named), or a worker died
            (the pool is then closed; so it is after an interrupt).
        """
        if self.closed:
            raise ValueError("the rollout pool is closed")
        key = self._key(start)
        chunks = _Guided(list(enumerate(batch)), self.processes)
        results, busy = {}, {}
        try:
            for w in self._workers:
                self._send(w, (kind, key), start, chunks, busy)
            while busy:
                for conn in wait(list(busy)):
                    w = busy.pop(conn)
                    results.update(conn.recv())
                    self._send(w, (kind, key), start, chunks, busy)
        except (EOFError, OSError) as exc:
            self.close()
            raise PlanningError(f"a rollout worker died ({type(exc).__name__}); the pool is closed and the "
                                "next batch starts a new one") from None
        except BaseException:  # an interrupt: replies still in flight must not answer the next batch
            self.close()
            raise
        out = [results[i] for i in range(len(batch))]
        for i, r in enumerate(out):
            if isinstance(r, BaseException):
                raise PlanningError(f"rollout {i} of the batch: {r}") from r
        return out

    @staticmethod
    def _send(w: _Worker, task, start, chunks, busy) -> None:
        """The next chunk to the idle worker ``w`` (its start state first if it lacks it)."""
        if chunks:
            kind, key = task
            w.hold(key, start)
            w.conn.send(("run", kind, key, chunks.pop()))
            busy[w.conn] = w
