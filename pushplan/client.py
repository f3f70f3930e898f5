"""Python client of ``pushplan serve`` (docs/service.md): one :class:`Client` per server,
one :class:`Session` per warm planner on it.

Units as everywhere in pushplan: SI, radians in the API.  Commands are rows ``(dx, dy,
dtheta)`` (m, m, rad) of the upper face; poses rows ``(x, y, yaw)`` (m, m, rad) of the
lower-face centroid from its rest pose, in the block frame of the scenario (``pushplan plan``'s).

A failed call raises :class:`ServiceError` with the gRPC status name (``code``) and the
server's one-line message (for bad input the CLI's own line).

>>> with Client("127.0.0.1:50051") as c:                      # doctest: +SKIP
...     s = c.open(scenario_path="scenarios/plan_rubber.toml")
...     first = s.plan()
...     s.replan(executed=first["commands"][:1], observed=[1.0e-4, 0.5e-4, 0.0])
"""

from __future__ import annotations

import json

import grpc

from .service.server import METHODS, SERVICE, TOKEN_HEADER


class ServiceError(RuntimeError):
    """A call the server refused or failed: ``code`` (gRPC status name, e.g.
    ``"INVALID_ARGUMENT"``) and the server's one-line ``message``."""

    def __init__(self, code: str, message: str):
        super().__init__(f"{code}: {message}")
        self.code, self.message = code, message


def _encode(obj) -> bytes:
    return json.dumps(obj).encode()


def _plain(value, depth: int):
    """Numbers (numpy's too) as JSON floats, nested ``depth`` lists deep (1: a pose, 2: rows);
    a value that is not numbers goes as it is, for the server to refuse naming its field."""
    try:
        return [float(v) for v in value] if depth == 1 else [[float(v) for v in row] for row in value]
    except (TypeError, ValueError):
        return value if isinstance(value, (str, int, float, list, dict)) or value is None else repr(value)


class Client:
    """A channel to the server at ``address`` (``HOST:PORT``); ``token`` for a server that
    asks for one; ``timeout`` (s) the deadline of each call."""

    def __init__(self, address: str, token: str | None = None, timeout: float = 300.0):
        self.channel = grpc.insecure_channel(address)
        self.timeout = timeout
        self._metadata = ((TOKEN_HEADER, f"Bearer {token}"),) if token else None
        self._stubs = {m: self.channel.unary_unary(f"/{SERVICE}/{m}", request_serializer=_encode,
                                                   response_deserializer=json.loads) for m in METHODS}

    def call(self, method: str, request: dict, timeout: float | None = None) -> dict:
        """One call; raises :class:`ServiceError`."""
        try:
            return self._stubs[method](request, timeout=timeout or self.timeout, metadata=self._metadata)
        except grpc.RpcError as e:
            raise ServiceError(e.code().name, e.details() or "") from None

    def open(self, scenario_toml: str | None = None, scenario_path: str | None = None, name: str | None = None,
             verify: bool = True) -> "Session":
        """A new session from a scenario's TOML text or a path the server may read; its
        planning (and, with ``verify``, verification) mesh built and factorised once."""
        request = {"verify": verify, "name": name}
        request |= {"scenario_toml": scenario_toml} if scenario_toml is not None else {"scenario_path": scenario_path}
        info = self.call("Open", request)
        return Session(self, info.pop("session"), info)

    def info(self) -> dict:
        """The server's open sessions and caps."""
        return self.call("Info", {})

    def close(self) -> None:
        self.channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Session:
    """A warm planner on the server (``id``); ``info`` what ``Open`` answered."""

    def __init__(self, client: Client, sid: str, info: dict):
        self.client, self.id, self.info = client, sid, info

    def _call(self, method: str, **fields) -> dict:
        return self.client.call(method, {"session": self.id, **{k: v for k, v in fields.items() if v is not None}})

    def plan(self, target=None, tolerance: float | None = None, baseline: bool = False) -> dict:
        """Plan the scenario's ``[plan]`` (or ``target`` (x, y, yaw), m and rad) from the
        session's current state: ``commands`` (K, 3), verified ``poses`` (K + 1, 3), ``status``."""
        return self._call("Plan", target=None if target is None else _plain(target, 1), tolerance=tolerance,
                          baseline=baseline)

    def replan(self, executed, observed, force=None, time: float | None = None, target=None,
               tolerance: float | None = None, closed_loop: bool = False) -> dict:
        """Report the pushes executed after the press (rows ``(dx, dy, dtheta)``) and the
        lower-face pose observed after them (``(x, y, yaw)``; force N, time s, kept), and
        re-plan the remaining steps warm.  Poses of the answer are relative to ``observed``.
        ``closed_loop``: re-plan as ``pushplan closed-loop`` does (the target shifted by the
        model's error since the last plan, a quarter of the tolerances, the planning mesh)."""
        return self._call("Replan", executed=_plain(executed, 2), observed=_plain(observed, 1),
                          force=None if force is None else _plain(force, 1),
                          time=time, target=None if target is None else _plain(target, 1), tolerance=tolerance,
                          closed_loop=closed_loop or None)

    def rollout(self, commands, jacobian: bool = False, mesh: str = "planning", release: bool = False) -> dict:
        """Roll ``commands`` out from the session's current state: the loaded ``poses``
        (K + 1, 3); with ``release`` (the scenario must have a ``[release]``), ``rest``
        ``{"pose", "status"}`` after it (else None); with ``jacobian``, ``jacobian`` (3, K, 3)
        ``d poses[-1] / d commands`` (``None`` where no derivative exists, ``nondifferentiable``
        says why) and, with ``release``, ``rest["jacobian"]``, the rest pose's."""
        return self._call("Rollout", commands=_plain(commands, 2), jacobian=jacobian,
                          mesh=mesh, release=release)

    def state(self) -> dict:
        return self._call("Info")

    def close(self) -> None:
        self._call("Close")
