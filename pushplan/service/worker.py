"""One service session: a warm :class:`~pushplan.planning.planner.PlanSession` in its own
process (a CPU-bound re-plan does not block other sessions; a crash stays in its session).

The server sends ``(op, payload)`` over a pipe and reads one reply per request:
``("ok", result)`` or ``("error", kind, message)``, ``kind`` one of ``"input"`` (bad
input, :class:`~pushplan.errors.InputError`: the session is left as it was), ``"solver"``
(:class:`~pushplan.errors.SolverFailure`) or ``"bug"`` (anything else: its type and
message, one line).  Payloads and results are JSON-able dicts in SI units (m, rad, N, s);
commands are rows ``(dx, dy, dtheta)``, poses rows ``(x, y, yaw)`` of the lower-face
centroid relative to its rest pose (the block frame of ``pushplan plan``).
"""

from __future__ import annotations

import dataclasses
import os
import time
import tomllib
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, SolverFailure
from .schema import nullable, pose, rows


@dataclass(frozen=True)
class _Aim:
    """What the session's last plan expects, for a ``closed_loop`` re-plan: the pose its
    path starts from (m, m, rad, from rest), that path (K + 1, 3) relative to it, its
    spring-back fractions (3,), the pushes executed when it was made, and ``drift`` (3,),
    the sum of the model's errors observed so far (``closed_loop.modifier``)."""

    origin: np.ndarray
    poses: np.ndarray
    springback: np.ndarray
    executed: int
    drift: np.ndarray


def _plan_doc(result) -> dict:
    """The reply to a plan or re-plan: commands and the verified lower-face path."""
    return {"status": result.status, "message": result.message, "commands": result.commands.tolist(),
            "poses": result.verified.lower.tolist(), "final": result.verified.final(result.spec.target_state).tolist(),
            "target": list(result.spec.target), "fe_rollouts": sum(result.rollouts.values()),
            "wall_time_s": result.timings.get("total", 0.0)}


class SessionState:
    """The session's planner and what the client reported; one method per request."""

    def __init__(self, scenario_text: str, name: str, verify: bool):
        from ..config import parse_scenario
        from ..config.plan import parse_plan
        from ..planning.planner import PlanSession

        try:
            data = tomllib.loads(scenario_text)
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"{name}: malformed TOML: {e}") from None
        self.scenario = parse_scenario(data, name=name)
        self.spec = parse_plan(self.scenario)
        t0 = time.perf_counter()
        self.session = PlanSession(self.scenario, self.spec, verify=verify)
        self.build_time = time.perf_counter() - t0
        self.observations: list[dict] = []
        self.aim: _Aim | None = None  # what the last plan expects, for a closed-loop re-plan

    def info(self) -> dict:
        from ..config.plan import press_commands

        s = self.scenario
        return {"name": s.name, "steps": self.spec.steps, "target": list(self.spec.target),
                "target_state": self.spec.target_state, "planning_elements": list(self.spec.planning_elements),
                "verification_elements": list(s.elements) if self.session.fine is not None else None,
                "build_time_s": self.build_time, "executed": len(self.session.executed), "pid": os.getpid(),
                "press": [[c.dx, c.dy, c.dz, c.dtheta] for c in press_commands(s)]}

    def _spec(self, payload: dict):
        """The session's spec with the request's ``target`` (m, m, rad) and ``tolerance`` (m)."""
        spec = self.spec
        if payload.get("target") is not None:
            spec = dataclasses.replace(spec, target=tuple(float(v) for v in pose(payload["target"], "target")))
        if payload.get("tolerance") is not None:  # a positive finite number: schema.check
            spec = dataclasses.replace(spec, tolerance=float(payload["tolerance"]))
        return spec

    def plan(self, payload: dict) -> dict:
        result = self.session.plan(self._spec(payload), baseline=bool(payload.get("baseline", False)))
        # from rest the plan's poses start at the rest pose; from a loaded state at a pose
        # the session was not told, so a closed-loop re-plan cannot follow it
        self.aim = (_Aim(np.zeros(3), result.verified.lower, result.springback.fractions, 0, np.zeros(3))
                    if not self.session.executed else None)
        return _plan_doc(result)

    def replan(self, payload: dict) -> dict:
        """Record an observation (the pushes executed after the press, the lower-face pose
        after them, optionally the force (N) and time (s)) and re-plan the remaining steps
        warm: the target less the observed pose, as ``pushplan plan --from`` does.  With
        ``closed_loop``, as ``pushplan closed-loop`` re-plans: the target shifted by the
        model's error observed since the last plan (``closed_loop.modifier``), within a
        quarter of the tolerances, corrected on the planning mesh alone."""
        from ..config.commands import planar_commands
        from ..identify.closed_loop import modifier, shifted_spec
        from ..planning.replan import Start, remaining_spec

        executed = rows(payload.get("executed"), "executed")
        self.spec.check_steps(executed, "executed")
        executed = planar_commands(executed)
        observed = pose(payload.get("observed"), "observed")
        spec = self._spec(payload)
        if len(executed) >= spec.steps:
            raise InputError(f"executed: {len(executed)} pushes executed, plan.steps = {spec.steps}: nothing to re-plan")
        closed_loop = bool(payload.get("closed_loop", False))
        drift = np.zeros(3)
        if closed_loop:  # checked before any change: an InputError leaves the session as it was
            if self.aim is None:
                raise InputError("closed_loop: the session's last plan must be a Plan from rest or a Replan")
            bias = self._bias(len(executed), observed)
            drift = self.aim.drift + bias
            spec = shifted_spec(spec, modifier(spec, bias, drift, self.aim.springback))
        start = Start(executed, observed)
        self.session.continue_from(executed)  # InputError before any change if they do not continue
        self.observations.append({"observed": observed.tolist(), "force": payload.get("force"),
                                  "time": payload.get("time")})
        result = self.session.plan(remaining_spec(spec, start), baseline=False, verify=not closed_loop)
        self.aim = _Aim(observed, result.verified.lower, result.springback.fractions, len(executed), drift)
        return _plan_doc(result) | {"observed": observed.tolist()}

    def _bias(self, executed: int, observed: np.ndarray) -> np.ndarray:
        """The model's error on the pushes executed since the last plan: the observed
        pose less the one that plan expected after them (m, m, rad)."""
        k = executed - self.aim.executed
        if not 1 <= k < len(self.aim.poses):
            raise InputError(f"executed: {k} pushes since the last plan; a closed_loop re-plan needs 1 to "
                             f"{len(self.aim.poses) - 1}")
        return observed - (self.aim.origin + self.aim.poses[k])

    def rollout(self, payload: dict) -> dict:
        """Roll commands out from the session's current state on one mesh: the loaded
        ``poses`` (K + 1, 3); with ``release``, the scenario's release after them and the
        ``rest`` pose; with ``jacobian``, the exact derivative (3, K, 3) of the final loaded
        pose, and of the rest pose in ``rest``, by the commands (docs/service.md)."""
        commands = rows(payload.get("commands"), "commands", max_rows=self.spec.steps * 10)
        if len(commands) == 0:
            raise InputError("commands: at least one row (dx, dy, dtheta) is needed, got []")
        self.spec.check_steps(commands, "commands")
        mesh = payload.get("mesh") or "planning"
        fe = {"planning": self.session.coarse, "verification": self.session.fine}[mesh]
        if fe is None:
            raise InputError(f"mesh: {mesh!r}, but this session was opened with verify false (no verification mesh)")
        release = bool(payload.get("release"))
        if release and fe.release is None:
            raise InputError("release: true, but the scenario has no [release] to run after the commands")
        if not payload.get("jacobian"):
            roll = fe.rollout(commands, release=release, warm=False)  # not the planner's
            return _rollout_doc(roll, release)
        if release and not fe.exact:
            raise InputError(f"release: true with jacobian: the scenario's release retreats (release.away = "
                             f"{list(fe.release.away)} m), whose rest pose has no exact derivatives; ask the "
                             "Jacobian with release false (the loaded poses') or the rest pose without jacobian")
        roll, final = fe.rollout_with_jacobian(commands, release=release)
        return _rollout_doc(roll, release, final)


def _rollout_doc(roll, release: bool, final=None) -> dict:
    """The reply to a rollout: which pose each output is, each Jacobian next to its pose,
    NaN (a derivative that does not exist) as null with the reason (docs/service.md)."""
    doc = {"poses": roll.lower.tolist(), "rest": None, "wall_time_s": roll.wall_time}
    if release:  # an unsettled block is a PlanningError (ABORTED): a rest pose given is settled
        doc["rest"] = {"pose": roll.rest.tolist(), "status": "settled"}
    if final is not None:
        doc |= {"jacobian": nullable(roll.loaded_jacobian), "nondifferentiable": roll.nondifferentiable}
        if release:
            doc["rest"]["jacobian"] = nullable(final)
    return doc


def _reply(conn, fn, *args) -> None:
    """Send ``fn(*args)`` with ``session_s`` and ``session_cpu_s``, the wall and CPU time (s)
    it took in this process, or the error."""
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        result = fn(*args)
        conn.send(("ok", result | {"session_s": time.perf_counter() - t0, "session_cpu_s": time.process_time() - c0}))
    except InputError as e:
        conn.send(("error", "input", " ".join(str(e).split())))
    except SolverFailure as e:
        conn.send(("error", "solver", " ".join(str(e).split())))
    except Exception as e:  # a bug: reported as one, the session goes on
        conn.send(("error", "bug", f"{type(e).__name__}: {' '.join(str(e).split())}"))


def ready() -> None:
    """Nothing: the process the server starts first, to wait for the fork server's imports."""


def worker_main(conn, scenario_text: str, name: str, verify: bool) -> None:
    """The session process: build the session, then answer requests until ``close`` or
    the pipe closes.  The first reply is the open's (``info`` or the error)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server stops its workers itself
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    state = None

    def open_():
        nonlocal state
        state = SessionState(scenario_text, name, verify)
        return state.info()

    _reply(conn, open_)
    if state is None:
        return
    ops = {"plan": state.plan, "replan": state.replan, "rollout": state.rollout, "info": lambda _: state.info()}
    while True:
        try:
            op, payload = conn.recv()
        except (EOFError, OSError):
            return
        if op == "close":
            conn.send(("ok", {}))
            return
        _reply(conn, ops[op], payload)
