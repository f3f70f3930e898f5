"""``pushplan serve [--address HOST:PORT]``: a resident planning service (docs/service.md).

Prints ``pushplan serve: listening on HOST:PORT`` once bound, serves until SIGTERM or
SIGINT, then stops taking calls, closes every session and exits 0 (it writes no file; a
reader of its stdout that has gone does not change that: :func:`_say`).
Exit 2 for bad flags: an address off loopback without ``--allow-remote`` and a token, an
unreadable token file, a ``--root`` that is not a folder.
"""

from __future__ import annotations

import os
import select
import signal
import socket
import sys
import threading

from ..errors import InputError

SIGNAL_BACKSTOP = 5.0
"""s between wake-ups of the waiting main thread should a signal's wake-up byte be lost."""


def _say(line: str) -> None:
    """Print ``line`` on stdout.  The lines are a report for whoever reads them; if that
    reader has gone (its pipe closed: ``BrokenPipeError``, Python ignores SIGPIPE), the
    server's work is unchanged, so the line and every later one are dropped: stdout is
    pointed at ``os.devnull``, the idiom of the ``signal`` module's "Note on SIGPIPE", so that
    the interpreter's flush at exit does not fail again on what is left in the buffer."""
    try:
        print(line, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def _token(path) -> str | None:
    if path is None:
        return None
    from ..config.files import read_text

    token = read_text(path, "--token-file").strip()
    if len(token) < 16:
        raise InputError(f"--token-file {path}: the token must have at least 16 characters, got {len(token)}")
    return token


def cmd_serve(args) -> int:
    from pathlib import Path

    from ..service.server import Limits, Server

    for root in args.root:
        if not Path(root).is_dir():
            raise InputError(f"--root {root}: not a folder")
    limits = Limits(max_sessions=args.max_sessions, max_request_bytes=args.max_request_bytes,
                    call_timeout=args.call_timeout, idle_timeout=args.idle_timeout)
    server = Server(args.address, limits, args.root, _token(args.token_file), args.allow_remote)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    # the signal may be delivered to one of gRPC's threads, and Python runs its handler only in
    # the main thread once that thread wakes: the C-level handler, in whichever thread, writes
    # the signal's number to the wakeup socket, which wakes the main thread's select (no polling;
    # the timeout is a backstop, one wake-up in SIGNAL_BACKSTOP s)
    wake, woken = socket.socketpair()
    wake.setblocking(False)
    previous = signal.set_wakeup_fd(wake.fileno(), warn_on_full_buffer=False)
    _say(f"pushplan serve: listening on {server.address}")
    try:
        while not stop.is_set():
            if select.select([woken], [], [], SIGNAL_BACKSTOP)[0]:
                woken.recv(64)
    finally:
        signal.set_wakeup_fd(previous)
        wake.close()
        woken.close()
        server.stop()
    _say("pushplan serve: stopped, sessions closed")
    return 0


def _positive(kind):
    def parse(text):
        import argparse

        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        return value
    return parse


def register(subparsers) -> None:
    p = subparsers.add_parser("serve", help="serve planning sessions over gRPC (docs/service.md)")
    p.add_argument("--address", default="127.0.0.1:50051", help="HOST:PORT to bind (default loopback 127.0.0.1:50051)")
    p.add_argument("--allow-remote", action="store_true", help="allow an address off loopback (needs --token-file)")
    p.add_argument("--token-file", help="file holding the token every call must carry (authorization: Bearer ...)")
    p.add_argument("--root", action="append", default=[], help="folder a client's scenario_path may be read from "
                   "(repeatable; none: only scenario text is accepted)")
    p.add_argument("--max-sessions", type=_positive(int), default=8, help="sessions at once (default 8)")
    p.add_argument("--max-request-bytes", type=_positive(int), default=1 << 20, help="request size cap (default 1 MiB)")
    p.add_argument("--call-timeout", type=_positive(float), default=300.0,
                   help="s a call may run before its session is stopped (default 300)")
    p.add_argument("--idle-timeout", type=_positive(float), default=600.0,
                   help="s after which an unused session is closed (default 600)")
    p.set_defaults(func=cmd_serve)
