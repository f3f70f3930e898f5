"""The compliant gripper: the upper face is one rigid plate whose vertical
motion is commanded and whose in-plane pose ``p = (x, y, theta)`` is tied to
the commanded pose ``c`` by springs ``k = (k_xy, k_xy, k_yaw)``
(:class:`~fe_contact.fem.loads.Gripper`).

The plate is in equilibrium when the springs balance the block's reaction:

    g(p) = F(p) - k (c - p) = 0,                                   (3,)

``F(p)`` the in-plane force and moment about the plate's centre (N, N, N m)
that the plate, held at pose ``p``, applies on the block after a step from
the state's configuration (:func:`plate_wrench`).  Each ``F(p)`` is one
displacement-driven step of the paper's algorithm (Box 3/4), from the same
start state: a step's result depends on its end pose only (one backward-Euler
increment of the friction law), so ``g`` is a function of ``p``, piecewise
smooth where nodes change between stick and slip.  It is solved by Broyden's
method started from ``dg/dp ~ k + k_block`` (``k_block`` the block's shear
stiffness and its torsional analogue); the tangent of each trial step is
handed to the next.  A stiff gripper (``k >> k_block``) converges in one or
two trials, a soft one in a few more.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .model import Command, Model, State, Status, StepReport, TangentCache
from .held import held_step, next_state
from .predictor import commanded_pose

MAX_TRIALS = 40
"""Limit on the trial plate poses of a step."""
PLATE_TOL = 3e-10
"""Plate out-of-balance ``|g|``, relative to the plate's force scale, at which the plate is in equilibrium."""


def _block_stiffness(model: Model) -> np.ndarray:
    """(3,) estimate of ``dF/dp`` of a sticking block: shear stiffness ``G A / H``
    in x, y and its torsional analogue ``G J / H``, ``J = A (lx^2 + ly^2) / 12``."""
    lx, ly, _ = model.mesh.size
    k = model.shear_stiffness
    return np.array([k, k, k * (lx**2 + ly**2) / 12.0])


def compliant_step(model: Model, state: State, command: Command, t0: float, local_problem_hook=None,
                   consume: bool = False) -> tuple[State, StepReport]:
    """One load step with the compliant gripper (see the module docstring).

    The report's ``gripper_force`` is the spring force ``k (c - p)`` and its
    ``plate`` the plate pose ``p``; the new state's commanded pose is ``c``.
    """
    k = model.gripper.stiffness
    translation, rotation = commanded_pose(state, command)
    c = np.array([translation[0], translation[1], rotation])
    length = np.array([1.0, 1.0, 1.0 / max(model.mesh.size)])  # moments to forces
    p = state.plate + np.array([command.dx, command.dy, command.dtheta])
    J = np.diag(k + _block_stiffness(model))
    trial_state, iterations = state, 0
    p_prev = g_prev = None
    for trial in range(MAX_TRIALS):
        eq, report = _trial(model, state, trial_state, command, p, translation[2], t0, local_problem_hook,
                            consume and trial == 0)
        iterations += report.newton_iterations
        if not report.converged:
            return state, replace(report, newton_iterations=iterations)
        spring = k * (c - p)
        g = report.gripper_force - spring
        scale = max(np.linalg.norm(report.gripper_force * length), np.linalg.norm(spring * length),
                    np.linalg.norm(k * (c - state.plate) * length), abs(report.upper_force[2]), model.weight)
        if np.linalg.norm(g * length) <= PLATE_TOL * scale or scale == 0:
            report = replace(report, gripper_force=spring, plate=p.copy(), newton_iterations=iterations)
            return next_state(state, eq, translation, rotation, report, plate=p), report
        if p_prev is not None and np.any(p != p_prev):  # Broyden's update of dg/dp
            dp, dg = p - p_prev, g - g_prev
            J = J + np.outer(dg - J @ dp, dp) / (dp @ dp)
        p_prev, g_prev = p.copy(), g
        p = p - np.linalg.solve(J, g)
        trial_state = replace(state, tangent=TangentCache(eq.tangent))
    message = (f"compliant gripper: plate not in equilibrium after {MAX_TRIALS} trial poses "
               f"(relative out-of-balance {np.linalg.norm(g * length) / scale:.3g})")
    return state, replace(report, status=Status.NEWTON_NOT_CONVERGED, message=message,
                          newton_iterations=iterations)


def _trial(model, state, trial_state, command, p, tz, t0, hook, consume):
    """A displacement-driven step from ``state`` with the plate at in-plane
    pose ``p`` (3,) and height ``tz``, m; ``trial_state`` lends its cached tangent."""
    dp = p - state.plate
    trial = Command(dx=dp[0], dy=dp[1], dz=command.dz, dtheta=dp[2])
    translation = np.array([p[0], p[1], tz])
    eq, report = held_step(model, trial_state, trial, translation, float(p[2]), t0, hook, consume)
    return eq, replace(report, command=command)
