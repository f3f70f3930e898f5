"""A recording written by a helper process that imports rerun while the caller works.

Importing rerun (its SDK and pyarrow) costs about 0.45 s of CPU, more than writing a
plan's recording (about 0.1 s).  A thread cannot hide it: the import holds the GIL
(measured on ``pushplan plan scenarios/plan_steel_case3.toml``: 1.87-2.02 s wall with the
import on a thread, 1.85-2.49 s without).  A child forked at the start imports rerun on
the other core while the parent plans, then waits for its one job: a function and its
arguments (plain, picklable data) sent through a pipe.  The parent waits for the job to
finish and gets its exception back, if any, before it commits its output transaction, so
the output stays atomic: the recording is written inside the transaction's folder, by
the same :class:`~pushplan.outputs.recording.Recorder` as in the parent.

Without ``os.fork`` (not POSIX) the job runs in the caller.  The child ignores SIGINT
(Ctrl-C interrupts the parent, which then ends the child) and never outlives the
parent's ``with`` block: leaving it without a job closes the pipe, and the child exits.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import pickle
import signal
import traceback

__all__ = ["RecordingProcess"]

_PR_SET_PDEATHSIG = 1


class RecordingProcess:
    """Context manager: a child process that has imported rerun, ready for one job.

    Example::

        with RecordingProcess() as writer:
            result = long_computation()
            writer.run(write_function, path, data)   # raises what write_function raised
    """

    def __init__(self) -> None:
        self._pid = None
        self._job = self._reply = None

    def __enter__(self) -> "RecordingProcess":
        if not hasattr(os, "fork"):
            return self
        job_r, job_w = os.pipe()
        reply_r, reply_w = os.pipe()
        parent = os.getpid()
        # Ctrl-C signals the whole process group: held back across the fork, so the child
        # ignores it from its first instruction (before, a SIGINT between the fork and its
        # SIG_IGN interrupted the child's import of rerun); the parent gets it after.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            pid = os.fork()
        except BaseException:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            raise
        if pid == 0:  # the child: never returns
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held SIGINT is now ignored
            os.close(job_w)
            os.close(reply_r)
            _serve(job_r, reply_w, parent)
        os.close(job_r)
        os.close(reply_w)
        self._pid = pid
        self._job, self._reply = os.fdopen(job_w, "wb"), os.fdopen(reply_r, "rb")
        try:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held Ctrl-C is raised here
        except BaseException:
            self._finish()
            raise
        return self

    def run(self, fn, *args) -> None:
        """``fn(*args)`` in the child (in this process without one), once; its
        exception, if any, raised here (a :class:`RuntimeError` with the child's
        traceback if the exception cannot be pickled or the child died)."""
        if self._pid is None:
            fn(*args)
            return
        try:
            pickle.dump((fn, args), self._job, protocol=pickle.HIGHEST_PROTOCOL)
            self._job.close()
            reply = pickle.load(self._reply)
        except (EOFError, BrokenPipeError) as exc:
            raise RuntimeError("the recording process died before it finished") from exc
        finally:
            self._finish()
        if reply is not None:
            raise reply

    def __exit__(self, *exc) -> None:
        self._finish()

    def _finish(self) -> None:
        if self._pid is None:
            return
        pid, self._pid = self._pid, None
        for f in (self._job, self._reply):
            f.close()  # the child, still waiting for a job, reads EOF and exits
        os.waitpid(pid, 0)


def _die_with_parent(parent: int) -> None:
    """Linux: SIGKILL this child when its parent dies (a ``kill -9`` of the run must not
    leave a writer behind in the transaction's folder); elsewhere nothing."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before prctl
        os._exit(1)


def _warm_up() -> None:
    """Write and delete a small plan recording (one element, the plan overlays) in a
    temporary folder: what a first recording builds once per process (rerun's stream and
    file sink, the blueprint, the archetypes' conversions) is then built before the job
    comes (measured: a plan's recording job 52-58 ms in a fresh child, 23-40 ms after this
    warm-up of about 40 ms, which runs while the parent plans)."""
    import tempfile
    from pathlib import Path

    from fe_contact import block_mesh

    from .recording import Recorder

    path = [[0.0, 0.0], [1e-3, 1e-3]]
    with tempfile.TemporaryDirectory() as folder:
        with Recorder(Path(folder) / "warm_up.rrd", "warm_up", block_mesh((0.01, 0.01, 0.01), (1, 1, 1)),
                      scenario={"friction": {"mu_x": 0.3, "mu_y": 0.2, "angle_deg": 0.0}}) as rec:
            rec.log_plan(target=[1e-3, 1e-3], predicted=path, verified=path, naive=path, cost=[1.0], first_step=0)


def _serve(job_r: int, reply_w: int, parent: int) -> None:
    """The child: import rerun (and :func:`_warm_up`), run the one job read from ``job_r``, send back None or
    its exception on ``reply_w``, exit without the parent's clean-up (``os._exit``)."""
    # the parent's objects out of this process's garbage collections: importing rerun
    # runs full collections, which would traverse them all and copy their pages (measured
    # under load: the import 0.86-1.19 s without, 0.62-1.08 s with; the gc module's advice
    # for forked children)
    gc.freeze()
    code = 0
    try:
        _die_with_parent(parent)
        try:
            import rerun  # noqa: F401  (the point: loaded before the job comes)
            import rerun.blueprint  # noqa: F401
            _warm_up()
        except Exception:
            pass  # only a head start: the job's own import or recording raises it, in the parent's terms
        with os.fdopen(job_r, "rb") as jobs:
            try:
                fn, args = pickle.load(jobs)
            except EOFError:  # the parent left without a job
                os._exit(0)
        try:
            fn(*args)
            reply = None
        except BaseException as exc:  # sent to the parent, which raises it
            exc.add_note("(raised in the recording process:)\n" + "".join(traceback.format_tb(exc.__traceback__)))
            reply = exc
        with os.fdopen(reply_w, "wb") as out:
            try:
                out.write(pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL))
            except Exception:  # an exception that does not pickle
                out.write(pickle.dumps(RuntimeError(
                    "writing the recording failed:\n" + "".join(traceback.format_exception(reply)))))
    except BaseException:
        code = 1
    finally:
        os._exit(code)
