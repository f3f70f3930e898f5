"""Sampling MPC on the FE model (issue 40 item 2): a rollout backend with judo's
contract and a cross-entropy (CEM) controller that reaches a target pose with it.

judo (``judo-rai`` 0.1.0 on PyPI, ``judo.utils.rollout_backend.RolloutBackend``)
asks a backend for ``rollout(x0, controls, last_policy_output=None) -> (states,
sensors, policy_outputs)`` with ``x0`` the state vector (nq + nv,) (tiled to
``num_threads`` rows), ``controls`` (num_threads, T, nu), and ``update(num_threads)``.
:class:`FeRolloutBackend` keeps that signature with nu = 3 (the command ``(dx, dy,
dtheta)``, m, m, rad), ``states`` the lower-face pose ``(x, y, yaw)`` after each
command (num_threads, T, 3), m and rad, and ``sensors`` the gripper's force on the
block (num_threads, T, 3), N.  What does not fit: the FE state (displacements,
contact forces, slip paths: thousands of numbers, path-dependent) is not a vector
``x0`` a controller can hand back, so the backend *holds* it (:meth:`advance` moves it
by an executed command) and ``x0`` must be the held state's pose (anything else is
refused: a pose does not determine the FE state).  judo's ``Controller`` also reads an
``MjModel`` (nq, nv, sensors) for its visualisation, which the FE model does not have:
a judo user calls the backend from their own loop, as :func:`cem_mpc` does.

Cost: each CEM iteration is one batch of ``num_threads`` rollouts of the remaining
horizon on the warm workers of :meth:`PushModel.pool`; at most ``iterations``
iterations per executed command (the cap is reached and reported).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .push_model import PushModel


class FeRolloutBackend:
    """judo's rollout backend on the FE model (module docstring).

    Parameters
    ----------
    push : PushModel
    num_threads : int
        Rollouts per call (judo sets it to its ``num_rollouts``).
    processes : int, optional
        Worker processes (default: the CPUs this process may use).
    """

    def __init__(self, push: PushModel, num_threads: int, processes: int | None = None):
        self.push, self.processes = push, processes
        self.update(num_threads)
        self.state = push.pressed.state
        self.pose = push.pressed.outputs[-1, :3].copy()

    def update(self, num_threads: int) -> None:
        """Set the rollouts per call."""
        if isinstance(num_threads, bool) or not isinstance(num_threads, int) or num_threads < 1:
            raise InputError(f"num_threads must be an integer >= 1, got {num_threads!r}")
        self.num_threads = num_threads

    def rollout(self, x0, controls, last_policy_output=None):
        """``(states, sensors, None)``: poses (n, T, 3), m and rad, and gripper
        forces (n, T, 3), N, of ``controls`` (n, T, 3) from the held FE state.

        Raises
        ------
        InputError
            ``x0`` is not the held state's pose (1e-12 m / rad), or bad controls.
        PlanningError
            A rollout failed.
        """
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        if x0.shape[1] != 3 or np.abs(x0 - self.pose).max() > 1e-12:
            raise InputError(f"x0 must be the held FE state's pose {self.pose.tolist()} (x, y, yaw), got "
                             f"{x0[0].tolist()}: a pose does not determine the FE state; use advance()")
        poses, forces = self.push.batch_rollouts_with_forces(controls, start=self.state, processes=self.processes)
        return poses, forces, None

    def advance(self, command) -> np.ndarray:
        """Execute ``command`` (3,) on the held FE state; the new pose (3,)."""
        self.state, self.pose = self.push.step(self.state, command)
        return self.pose


@dataclass(frozen=True)
class SamplingResult:
    """What :func:`cem_mpc` executed.

    Attributes
    ----------
    commands, poses : ndarray, shape (K, 3)
        Executed commands and the lower-face poses after them, m and rad.
    error : float
        Final in-plane distance to the target, m.
    reached : bool
        ``error <= tolerance``.
    rollouts, iterations : int
        FE rollouts and CEM iterations spent.
    wall_s : float
        s.
    """

    commands: np.ndarray
    poses: np.ndarray
    error: float
    reached: bool
    rollouts: int
    iterations: int
    wall_s: float


def _clip(u: np.ndarray, max_step: float) -> np.ndarray:
    """``u`` (..., 3) with each step's length cut to ``max_step``, m."""
    length = np.hypot(u[..., 0], u[..., 1])
    scale = np.minimum(1.0, max_step / np.maximum(length, 1e-300))
    return np.concatenate([u[..., :2] * scale[..., None], u[..., 2:]], axis=-1)


def cem_mpc(backend: FeRolloutBackend, target, steps: int, max_step: float, tolerance: float,
            iterations: int = 30, elites: int = 6, seed: int = 0) -> SamplingResult:
    """Receding-horizon CEM to the lower-face position ``target`` (x, y), m, in
    ``steps`` commands of at most ``max_step`` m, yaw held (``dtheta = 0``).

    Each executed command: CEM on the remaining horizon from the held FE state
    (samples ``mean + sigma * N(0, 1)``, the mean itself kept as sample 0; cost the
    final distance to the target; the ``elites`` best set the next mean and sigma)
    until the best rollout ends within ``tolerance`` or ``iterations``; then the
    best sample's first command is executed and the rest warm-starts the next one
    (its sample 0).  ``reached`` is measured on the executed state, not predicted.
    """
    rng = np.random.default_rng(seed)
    target = np.asarray(target, dtype=float)
    t0, rollouts, spent = time.perf_counter(), 0, 0
    executed, poses, mean = [], [], None
    for k in range(steps):
        H = steps - k
        if mean is None or len(mean) != H:
            mean = np.zeros((H, 3))
            mean[:, :2] = (target - backend.pose[:2]) / H  # the straight split: the naive plan
        sigma = np.full((H, 3), max_step / 4)
        sigma[:, 2] = 0.0
        best = None
        for _ in range(iterations):
            u = mean + sigma * rng.standard_normal((backend.num_threads, H, 3))
            u[0] = mean
            u = _clip(u, max_step)
            states, _, _ = backend.rollout(backend.pose, u)
            cost = np.hypot(*(states[:, -1, :2] - target).T)
            rollouts, spent = rollouts + len(u), spent + 1
            order = np.argsort(cost)
            if best is None or cost[order[0]] < best[0]:
                best = (cost[order[0]], u[order[0]])
            if best[0] <= tolerance:  # the model is the plant: the rest of this rollout is what will happen
                break
            mean, sigma = u[order[:elites]].mean(axis=0), u[order[:elites]].std(axis=0) + 1e-3 * max_step
            sigma[:, 2] = 0.0
        executed.append(best[1][0])
        poses.append(backend.advance(best[1][0]))
        mean = best[1][1:]
    error = float(np.hypot(*(poses[-1][:2] - target)))
    return SamplingResult(np.array(executed), np.array(poses), error, error <= tolerance, rollouts, spent,
                          time.perf_counter() - t0)


try:  # judo installed: the backend is one of its RolloutBackends (isinstance holds)
    from judo.utils.rollout_backend import RolloutBackend as _JudoBackend
except ImportError:  # judo is not needed: the contract is the signature
    pass
else:
    _JudoBackend.register(FeRolloutBackend)
