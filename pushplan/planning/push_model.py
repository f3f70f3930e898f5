"""The FE push model as a plugin for any planner: steps, rollouts, exact
Jacobians, batched rollouts from any FE state on warm worker processes
(:mod:`pushplan.planning.batch`, kept until :meth:`PushModel.close` or the end
of a ``with`` block), and a CasADi function with an exact Jacobian for a user's
``Opti`` problem.

Units, once: SI (m, N, Pa, kg/m^3) and radians in Python; scenario files write
angles in degrees (``angle_deg``, ``dtheta_deg``) and :meth:`PushModel.from_scenario`
converts them.  Commands are in-plane increments of the gripper ``(dx, dy,
dtheta)`` (m, m, rad) after the scenario's press; poses are the lower face's
``(x, y, yaw)`` (centroid displacement from the undeformed block, m, and
best-fit yaw, rad) after each command.  Commands are checked at the boundary:
a step longer than the block or a turn beyond pi is refused as a probable unit
error (:class:`~pushplan.errors.InputError` naming the entry).

Derivatives are exact (implicit function theorem through the converged FE
steps, :func:`fe_contact.rollout_derivatives`), with respect to the commands
and to :data:`PARAMETERS` (the press included).  A rollout with its Jacobian
costs about 1.3x a plain rollout plus about one back-substitution per input and
step (``benchmarks/derivatives.py``); for one scalar objective of many inputs,
:func:`fe_contact.rollout_gradient` (reverse mode) is cheaper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi
import numpy as np

from fe_contact import PARAMETERS, Model, RolloutDerivatives, State, StepReport, applicable_parameters, rollout_derivatives  # noqa: F401 (PARAMETERS: re-exported)

from ..config.commands import PLANAR_COMPONENTS, planar_commands
from ..config.plan import press_commands
from ..config.scenario import Scenario
from ..errors import InputError
from ..run import drive
from .batch import RolloutPool
from .rollouts import PlanningError



@dataclass(frozen=True)
class PushJacobian:
    """Poses of a rollout and their exact derivatives.

    Attributes
    ----------
    poses : ndarray, shape (K, 3)
        Lower-face ``(x, y, yaw)`` after each command, m, m, rad.
    forces : ndarray, shape (K, 3)
        Force of the gripper on the block after each command, N (world).
    d_commands : ndarray, shape (K, 3, K, 3)
        ``d poses[k, i] / d commands[j, c]``.
    d_parameters : ndarray, shape (K, 3, P)
        ``d poses[k, i] / d parameters[p]``.
    d_forces : ndarray, shape (K, 3, K, 3)
        ``d forces[k, i] / d commands[j, c]``.
    parameters : tuple of str
    """

    poses: np.ndarray
    forces: np.ndarray
    d_commands: np.ndarray
    d_parameters: np.ndarray
    d_forces: np.ndarray
    parameters: tuple


class PushModel:
    """A pressed FE block that planners roll commands out on (module docstring).

    Parameters
    ----------
    model : fe_contact.Model
    press : sequence of fe_contact.Command
        Applied once from the undeformed block; every rollout starts after it.
    parameters : sequence of str, optional
        Parameters to differentiate (default: all that apply to ``model``).
    """

    def __init__(self, model: Model, press, parameters=None):
        self.model = model
        self.press = tuple(press)
        self.parameters = applicable_parameters(model) if parameters is None else tuple(parameters)
        self.rollouts_run = 0
        self._pressed = None
        self._last = (None, None)
        self._pool: RolloutPool | None = None
        self._callbacks = []  # CasADi calls back into these: they live as long as the model

    @classmethod
    def from_scenario(cls, scenario: Scenario, elements=None, parameters=None) -> "PushModel":
        """The model of ``scenario`` (mesh ``elements`` if given), its ``[[load]]``
        entries the press.

        Raises
        ------
        InputError
            A bad scenario value, a press that is not one, or an unknown parameter.
        """
        model = scenario.model(elements)
        for p in parameters or ():
            if p not in applicable_parameters(model):
                raise InputError(f"parameters: {p!r} has no derivative here; choose from "
                                 f"{', '.join(applicable_parameters(model))}")
        return cls(model, press_commands(scenario), parameters)

    def __getstate__(self):  # to a pool worker: no factorised tangents, no CasADi objects
        return {"model": self.model, "press": self.press, "parameters": self.parameters}

    def __setstate__(self, state):
        self.__init__(state["model"], state["press"], state["parameters"])

    @property
    def pressed(self):
        """The press and its parameter derivatives (:class:`fe_contact.RolloutDerivatives`), computed once.

        Raises
        ------
        PlanningError
            A press step did not converge.
        """
        if self._pressed is None:
            pressed = rollout_derivatives(self.model, self.press, parameters=self.parameters)
            if not pressed.converged:
                raise PlanningError(f"the press failed: {pressed.message}")
            self._pressed = pressed
        return self._pressed

    def commands(self, commands) -> np.ndarray:
        """``commands`` as a checked (K, 3) array ``(dx, dy, dtheta)``, m and rad.

        Raises
        ------
        InputError
            Not (K, 3), not finite, a step longer than the block or a turn beyond pi.
        """
        a = np.asarray(commands, dtype=float)
        if a.ndim == 1 and a.size % 3 == 0:
            a = a.reshape(-1, 3)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
            raise InputError(f"commands must have shape (K, 3) as (dx, dy, dtheta), got {np.shape(commands)}")
        size = max(self.model.mesh.size)
        for k, (dx, dy, dtheta) in enumerate(a):
            for name, v in (("dx", dx), ("dy", dy), ("dtheta", dtheta)):
                if not math.isfinite(v):
                    raise InputError(f"commands[{k}].{name} must be finite, got {v}")
            if math.hypot(dx, dy) > size:
                raise InputError(f"commands[{k}]: a step of {math.hypot(dx, dy):g} m is longer than the block "
                                 f"({size:g} m): commands are in m")
            if abs(dtheta) > math.pi:
                raise InputError(f"commands[{k}].dtheta = {dtheta:g} is beyond pi: commands are in rad")
        return a

    def step(self, state: State, command) -> tuple[State, np.ndarray]:
        """One command ``(dx, dy, dtheta)`` from ``state`` (the pressed one:
        ``model.pressed.state``): the new state and the lower-face pose (3,).

        Raises
        ------
        PlanningError
            The step did not converge.
        """
        state, report = self.step_report(state, command)
        return state, np.array([*report.lower_centroid[:2], report.lower_yaw])

    def step_report(self, state: State, command) -> tuple[State, StepReport]:
        """:meth:`step` with the step's whole :class:`fe_contact.StepReport` (forces
        on the block, the gripper's wrench, contact state) instead of the pose.

        Raises
        ------
        InputError, PlanningError
        """
        a = self.commands(command)
        if a.shape[0] != 1:
            raise InputError(f"command must be one (dx, dy, dtheta), got shape {np.shape(command)}")
        run = self._drive(a, state)
        return run.state, run.reports[-1]

    def _drive(self, commands: np.ndarray, state: State):
        run = drive(self.model, planar_commands(commands), state)
        if not run.completed:
            f = run.summary.failure
            raise PlanningError(f"FE step {f.step} failed ({f.status}): {f.message}")
        return run

    def _start(self, start) -> RolloutDerivatives | State:
        """``start`` checked: None is the press (:attr:`pressed`)."""
        if start is None:
            return self.pressed
        if isinstance(start, RolloutDerivatives) and start.converged or isinstance(start, State):
            return start
        raise InputError(f"start must be an fe_contact State or a converged RolloutDerivatives, "
                         f"got {type(start).__name__}")

    def rollout(self, commands, start=None) -> np.ndarray:
        """Lower-face poses (K, 3) after each of the commands (K, 3) from ``start``
        (an :class:`fe_contact.State` of this model, e.g. one :meth:`step` returned;
        default: the press).

        Raises
        ------
        InputError, PlanningError
        """
        return self.rollout_with_forces(commands, start)[0]

    def rollout_with_forces(self, commands, start=None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`rollout`'s poses (K, 3) and the force of the gripper on the block
        after each command (K, 3), N (world).

        Raises
        ------
        InputError, PlanningError
        """
        start = self._start(start)
        state = start.state if isinstance(start, RolloutDerivatives) else start
        run = self._drive(self.commands(commands), state)
        self.rollouts_run += 1
        poses = np.array([[*r.lower_centroid[:2], r.lower_yaw] for r in run.reports])
        return poses, np.array([r.upper_force for r in run.reports])

    def rollout_with_jacobian(self, commands, start=None) -> PushJacobian:
        """Poses, forces and their exact derivatives for the commands (K, 3) from
        ``start`` (default: the press; the last result from the press is kept: a
        CasADi solver asks for the value and the Jacobian at the same point).
        From the press (or a converged :class:`fe_contact.RolloutDerivatives`) the
        parameter derivatives include its dependence on the parameters; from a
        plain :class:`fe_contact.State` it is held fixed and ``d_parameters`` is
        (K, 3, 0).

        Raises
        ------
        InputError, PlanningError
        """
        a = self.commands(commands)
        key = a.tobytes()
        if start is None and self._last[0] == key:
            return self._last[1]
        start = self._start(start)
        if isinstance(start, RolloutDerivatives):
            result = rollout_derivatives(self.model, planar_commands(a), start=start)
        else:
            result = rollout_derivatives(self.model, planar_commands(a), state=start, parameters=())
        if not result.converged:
            raise PlanningError(f"FE rollout failed: {result.message}")
        self.rollouts_run += 1
        d_cmd = result.d_commands[:, :, :, PLANAR_COMPONENTS]
        jac = PushJacobian(result.outputs[:, :3], result.outputs[:, 3:6], d_cmd[:, :3], result.d_parameters[:, :3],
                           d_cmd[:, 3:6], result.parameters)
        if start is self._pressed:
            self._last = (key, jac)
        return jac

    def pool(self, processes: int | None = None) -> RolloutPool:
        """The model's :class:`~pushplan.planning.batch.RolloutPool` of warm workers,
        started on first use and kept until :meth:`close` (a different
        ``processes`` restarts it; default: the CPUs this process may use)."""
        if self._pool is not None and (self._pool.closed or processes not in (None, self._pool.processes)):
            self._pool.close()
            self._pool = None
        if self._pool is None:
            self.pressed  # computed once here: the workers start from this process's press  # noqa: B018
            self._pool = RolloutPool(self, processes)
        return self._pool

    def _batch(self, controls, start, processes, kind: str) -> list:
        a = np.asarray(controls, dtype=float)
        if a.ndim != 3 or a.shape[2] != 3 or 0 in a.shape[:2]:
            raise InputError(f"controls must have shape (n, T, 3) as (dx, dy, dtheta), got {np.shape(controls)}")
        batch = [self.commands(c) for c in a]
        out = self.pool(processes).run(kind, batch, self._start(start))
        self.rollouts_run += len(batch)
        return out

    def batch_rollouts(self, controls, start=None, processes: int | None = None) -> np.ndarray:
        """Poses (n, T, 3) of n command sequences ``controls`` (n, T, 3) from
        ``start`` (as :meth:`rollout`), on the warm workers of :meth:`pool`:
        the numbers of n :meth:`rollout` calls.

        Raises
        ------
        InputError, PlanningError
            Bad controls; a rollout failed (the first failing one is named).
        """
        return np.array(self._batch(controls, start, processes, "poses"))

    def batch_rollouts_with_forces(self, controls, start=None, processes: int | None = None):
        """Poses and gripper forces, each (n, T, 3), of n command sequences ``controls``
        (n, T, 3) from ``start`` (as :meth:`rollout_with_forces`), on the warm workers.

        Raises
        ------
        InputError, PlanningError
        """
        out = self._batch(controls, start, processes, "forces")
        return np.array([p for p, _ in out]), np.array([f for _, f in out])

    def batch_rollouts_with_jacobian(self, controls, start=None, processes: int | None = None) -> list[PushJacobian]:
        """:meth:`rollout_with_jacobian` of each of n command sequences ``controls``
        (n, T, 3) from ``start``, on the warm workers of :meth:`pool`.

        Raises
        ------
        InputError, PlanningError
        """
        return self._batch(controls, start, processes, "jacobian")

    def close(self) -> None:
        """Stop the pool's workers, if any (the model stays usable)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def __enter__(self) -> "PushModel":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def casadi_function(self, K: int, name: str = "fe_push") -> casadi.Function:
        """A CasADi function ``u (3K) -> poses (3K)`` (commands and poses flattened
        step-major) with the exact Jacobian, for ``Opti`` constraints and
        objectives.  The model keeps the callback objects alive.  Use a
        quasi-Newton Hessian (ipopt ``hessian_approximation = limited-memory``)."""
        if isinstance(K, bool) or not isinstance(K, int) or K < 1:
            raise InputError(f"K must be an integer >= 1, got {K!r}")
        callback = _PosesCallback(name, self, K)
        self._callbacks.append(callback)
        return callback


class _PosesCallback(casadi.Callback):
    """``u (3K,) -> poses (3K,)``; its Jacobian is :class:`_JacobianCallback`."""

    def __init__(self, name: str, push: PushModel, K: int):
        casadi.Callback.__init__(self)
        self.push, self.K = push, K
        self.jacobian_callback = None
        self.construct(name, {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return casadi.Sparsity.dense(3 * self.K, 1)

    def get_sparsity_out(self, i):
        return casadi.Sparsity.dense(3 * self.K, 1)

    def eval(self, arg):
        return [casadi.DM(self.push.rollout_with_jacobian(np.array(arg[0]).ravel()).poses.ravel())]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self.jacobian_callback = _JacobianCallback(name, self.push, self.K, opts)
        return self.jacobian_callback


class _JacobianCallback(casadi.Callback):
    """``(u, poses) -> d poses / d u`` (3K, 3K), exact."""

    def __init__(self, name: str, push: PushModel, K: int, opts):
        casadi.Callback.__init__(self)
        self.push, self.K = push, K
        self.construct(name, opts)

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return casadi.Sparsity.dense(3 * self.K, 1)

    def get_sparsity_out(self, i):
        return casadi.Sparsity.dense(3 * self.K, 3 * self.K)

    def eval(self, arg):
        jac = self.push.rollout_with_jacobian(np.array(arg[0]).ravel())
        return [casadi.DM(jac.d_commands.reshape(3 * self.K, 3 * self.K))]
