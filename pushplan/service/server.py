"""``pushplan serve``: the gRPC server of planning sessions (docs/service.md).

Each session is one process (:mod:`.worker`) holding a warm
:class:`~pushplan.planning.planner.PlanSession`; the server only routes requests to it,
one at a time per session, and enforces the limits: request size
(:attr:`Limits.max_request_bytes`, gRPC's own check), sessions
(:attr:`Limits.max_sessions`, refused at once when full), a deadline per call
(:attr:`Limits.call_timeout`: the session's worker is stopped past it), the wait for a
session another call holds (:attr:`Limits.busy_wait`), idle sessions closed after
:attr:`Limits.idle_timeout`.  Errors are gRPC status codes with the CLI's one-line message
(:data:`STATUS_OF`).
"""

from __future__ import annotations

import hmac
import ipaddress
import itertools
import json
import multiprocessing
import threading
import time
from concurrent import futures
from dataclasses import dataclass, field
from pathlib import Path

import grpc

from ..errors import InputError
from .schema import check, strict_json
from .worker import ready, worker_main

SERVICE = "pushplan.Planner"
"""The gRPC service name; methods are ``/pushplan.Planner/<Method>``."""
METHODS = ("Open", "Plan", "Replan", "Rollout", "Info", "Close")
STATUS_OF = {"input": grpc.StatusCode.INVALID_ARGUMENT, "solver": grpc.StatusCode.ABORTED,
             "bug": grpc.StatusCode.INTERNAL}
"""A worker's error kind -> status: bad input (CLI exit 2), solver failure (exit 3), bug (exit 1)."""
TOKEN_HEADER = "authorization"
"""Metadata key of the token: ``authorization: Bearer <token>``."""


@dataclass(frozen=True)
class Limits:
    """The server's caps (s, bytes, count)."""

    max_sessions: int = 8
    max_request_bytes: int = 1 << 20
    call_timeout: float = 300.0
    open_timeout: float = 300.0
    busy_wait: float = 5.0
    idle_timeout: float = 600.0


@dataclass
class _Session:
    id: str
    process: multiprocessing.Process
    conn: object
    lock: threading.Lock = field(default_factory=threading.Lock)
    last_used: float = field(default_factory=time.monotonic)

    def stop(self, wait: float = 2.0) -> None:
        """Ask the worker to close; terminate it if it does not within ``wait`` s."""
        try:
            if self.lock.acquire(timeout=0):  # idle: a clean close
                try:
                    self.conn.send(("close", None))
                finally:
                    self.lock.release()
        except (OSError, ValueError):
            pass
        self.process.join(wait)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(wait)
        self.conn.close()


class _Abort(Exception):
    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code = code


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


PRELOAD = ("pushplan.service.worker", "pushplan.config.scenario", "pushplan.planning.planner",
           "pushplan.planning.replan", "pushplan.identify.closed_loop")
"""Imported once by the fork server, so a session's process starts with them (numpy, scipy,
CasADi, fe_contact's kernels): an open pays the model's build only."""


def _context():
    """Sessions fork from a fork server started clean (not from the server, whose gRPC
    threads a fork would copy), with :data:`PRELOAD` imported once."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOAD))
    # the fork server's imports (seconds) happen now, before the server says it listens, not
    # inside the first Open: a first process from it waits for them
    first = ctx.Process(target=ready, name="pushplan-forkserver-ready")
    first.start()
    first.join()
    return ctx


class Planner:
    """The service: sessions by id, the limits, the token and the folders a scenario path
    may be read from (``roots``; none: paths are refused, only TOML text is accepted)."""

    def __init__(self, limits: Limits = Limits(), roots=(), token: str | None = None):
        self.limits, self.token = limits, token
        self.roots = tuple(Path(r).resolve() for r in roots)
        self.sessions: dict[str, _Session] = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._opening = 0
        self._context = _context()

    # -- request handling ------------------------------------------------------------
    def handler(self, method: str):
        fn = getattr(self, "_" + method.lower())

        def handle(raw: bytes, context) -> bytes:
            t0 = time.perf_counter()
            try:
                self._authorise(context)
                try:
                    request = json.loads(raw.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError) as e:
                    raise _Abort(grpc.StatusCode.INVALID_ARGUMENT, f"request: not a UTF-8 JSON object ({e})") from None
                if not isinstance(request, dict):
                    raise _Abort(grpc.StatusCode.INVALID_ARGUMENT, "request: not a JSON object")
                check(method, request)  # before any session is touched
                answer = fn(request, context)
                try:
                    return strict_json(answer | {"server_s": time.perf_counter() - t0})
                except ValueError as e:  # a non-finite number the session did not encode: a bug
                    raise _Abort(grpc.StatusCode.INTERNAL, f"{method}: the answer is not strict JSON ({e})") from None
            except _Abort as e:
                context.abort(e.code, str(e))
            except InputError as e:
                context.abort(grpc.StatusCode.INVALID_ARGUMENT, " ".join(str(e).split()))

        return grpc.unary_unary_rpc_method_handler(handle)

    def _authorise(self, context) -> None:
        if self.token is None:
            return
        given = dict(context.invocation_metadata()).get(TOKEN_HEADER, "")
        if not hmac.compare_digest(given.encode(), f"Bearer {self.token}".encode()):
            raise _Abort(grpc.StatusCode.UNAUTHENTICATED, "missing or wrong token (metadata authorization: Bearer ...)")

    def _scenario_text(self, request: dict) -> tuple[str, str]:
        """The scenario's TOML text and name: ``scenario_toml``, or ``scenario_path`` inside
        one of the server's folders."""
        text, path = request.get("scenario_toml"), request.get("scenario_path")
        if (text is None) == (path is None):
            raise InputError("Open: give exactly one of scenario_toml (text) and scenario_path")
        if text is not None:  # both strings: checked by schema.check
            return text, str(request.get("name") or "scenario")
        resolved = Path(path).resolve()
        if not any(resolved.is_relative_to(r) for r in self.roots):
            raise _Abort(grpc.StatusCode.PERMISSION_DENIED,
                         f"scenario_path: {path} is outside the folders this server reads (--root)")
        from ..config.files import read_text

        return read_text(resolved, "scenario"), resolved.stem

    def _open(self, request: dict, context) -> dict:
        text, name = self._scenario_text(request)
        with self._lock:
            if len(self.sessions) + self._opening >= self.limits.max_sessions:
                raise _Abort(grpc.StatusCode.RESOURCE_EXHAUSTED,
                             f"sessions: {self.limits.max_sessions} open, the server's cap (--max-sessions)")
            self._opening += 1
            sid = f"s{next(self._ids)}"
        try:
            parent, child = self._context.Pipe()
            proc = self._context.Process(target=worker_main, args=(child, text, name, request.get("verify") is not False),
                                         daemon=True, name=f"pushplan-session-{sid}")
            proc.start()
            child.close()
            session = _Session(sid, proc, parent)
            with session.lock:
                info = self._receive(session, self.limits.open_timeout, context)
            with self._lock:
                self.sessions[sid] = session
            return {"session": sid, **info}
        finally:
            with self._lock:
                self._opening -= 1

    def _receive(self, session: _Session, timeout: float, context) -> dict:
        """The worker's reply, within ``timeout`` s (the worker is stopped past it).  The
        client's own deadline does not stop the worker: a client that leaves mid-call
        leaves the session as the call finishes it."""
        limit = timeout
        try:
            ready = session.conn.poll(limit)
            reply = session.conn.recv() if ready else None
        except (EOFError, OSError):
            reply = ()
        if not reply:
            self._drop(session)
            if reply is None:
                raise _Abort(grpc.StatusCode.DEADLINE_EXCEEDED, f"session {session.id}: no answer within {limit:.3g} s,"
                             " session closed")
            raise self._ended(session)
        if reply[0] == "ok":
            return reply[1]
        raise _Abort(STATUS_OF[reply[1]], reply[2])

    def _ended(self, session: _Session) -> _Abort:
        """The error of a call on a session whose process ended (already dropped)."""
        return _Abort(grpc.StatusCode.INTERNAL, f"session {session.id}: its process ended "
                      f"(exit code {session.process.exitcode}), session closed")

    def _drop(self, session: _Session) -> None:
        with self._lock:
            self.sessions.pop(session.id, None)
        session.process.terminate()
        session.process.join(2.0)

    def _session(self, request: dict) -> _Session:
        sid = request.get("session")
        with self._lock:
            session = self.sessions.get(sid) if isinstance(sid, str) else None
        if session is None:
            raise _Abort(grpc.StatusCode.NOT_FOUND, f"session: no open session {sid!r} (closed, idle-closed or never opened)")
        return session

    def _call(self, op: str, request: dict, context) -> dict:
        session = self._session(request)
        if not session.lock.acquire(timeout=self.limits.busy_wait):
            raise _Abort(grpc.StatusCode.UNAVAILABLE, f"session {session.id}: busy with another call for "
                         f"{self.limits.busy_wait:g} s (one call at a time per session)")
        try:
            if session.id not in self.sessions:
                raise _Abort(grpc.StatusCode.NOT_FOUND, f"session: {session.id!r} was closed")
            session.last_used = time.monotonic()
            try:
                session.conn.send((op, request))
            except (OSError, ValueError):  # the process ended and its end of the pipe is closed
                self._drop(session)
                raise self._ended(session) from None
            return self._receive(session, self.limits.call_timeout, context)
        finally:
            session.last_used = time.monotonic()
            session.lock.release()

    def _plan(self, request, context):
        return self._call("plan", request, context)

    def _replan(self, request, context):
        return self._call("replan", request, context)

    def _rollout(self, request, context):
        return self._call("rollout", request, context)

    def _info(self, request, context):
        if request.get("session") is None:
            with self._lock:
                return {"sessions": sorted(self.sessions), "max_sessions": self.limits.max_sessions,
                        "idle_timeout_s": self.limits.idle_timeout, "max_request_bytes": self.limits.max_request_bytes}
        return self._call("info", request, context)

    def _close(self, request, context):
        session = self._session(request)
        with self._lock:
            self.sessions.pop(session.id, None)
        session.stop()
        return {"session": session.id, "closed": True}

    # -- housekeeping ----------------------------------------------------------------
    def close_idle(self, now: float | None = None) -> list[str]:
        """Close the sessions unused for :attr:`Limits.idle_timeout` s; returns their ids."""
        now = time.monotonic() if now is None else now
        with self._lock:
            idle = [s for s in self.sessions.values()
                    if now - s.last_used > self.limits.idle_timeout and not s.lock.locked()]
            for s in idle:
                self.sessions.pop(s.id, None)
        for s in idle:
            s.stop()
        return [s.id for s in idle]

    def close_all(self) -> None:
        with self._lock:
            sessions, self.sessions = list(self.sessions.values()), {}
        for s in sessions:
            s.stop()


class Server:
    """A running service: ``port``, ``stop()``.  ``address`` ``HOST:PORT`` (port 0: any
    free one); a host off loopback needs ``allow_remote`` and a ``token``."""

    def __init__(self, address: str = "127.0.0.1:0", limits: Limits = Limits(), roots=(), token: str | None = None,
                 allow_remote: bool = False):
        host = address.rsplit(":", 1)[0]
        if not _loopback(host) and not (allow_remote and token):
            raise InputError(f"--address {address}: off loopback needs --allow-remote and a token (--token-file)")
        self.planner = Planner(limits, roots, token)
        self._server = grpc.server(
            futures.ThreadPoolExecutor(max_workers=2 * limits.max_sessions + 4),
            options=[("grpc.max_receive_message_length", limits.max_request_bytes),
                     ("grpc.so_reuseport", 0)])
        self._server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler(
            SERVICE, {m: self.planner.handler(m) for m in METHODS}),))
        self.port = self._server.add_insecure_port(address)
        if self.port == 0:
            raise InputError(f"--address {address}: cannot bind")
        self.address = f"{host}:{self.port}"
        self._stopped = threading.Event()
        self._reaper = threading.Thread(target=self._reap, daemon=True, name="pushplan-idle-reaper")
        self._server.start()
        self._reaper.start()

    def _reap(self) -> None:
        period = min(max(self.planner.limits.idle_timeout / 4, 0.05), 5.0)
        while not self._stopped.wait(period):
            self.planner.close_idle()

    def stop(self, grace: float = 1.0) -> None:
        """Stop taking calls, let running ones end within ``grace`` s, close every session."""
        self._stopped.set()
        self._server.stop(grace).wait()
        self.planner.close_all()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
