"""A position-controlled arm that reaches its command under the block's load
(issue 40 item 5): integral action, and the coupling's reaction fed forward, on
MuJoCo ``<position>`` actuators.

A ``<position>`` actuator is a P controller (``kv`` / ``dampratio`` make it PD) on its
joint: the force ``kp (u - q) - kv qdot`` (N or N m; ``u`` the ctrl, ``q`` the joint
position).  Held against a constant load ``f`` it rests at ``q = u - f / kp``: it sags.
The gantry of scenarios/mujoco_arm.xml (kp = 2e5 N/m) pressing a block of E = 8 MPa,
50 x 35 x 20 mm by a commanded 0.5 mm reaches only 0.1 mm and presses with 82 N
instead of the 436 N of a gripper that follows its command (docs/mujoco-coupling.md).
A real position-controlled arm does not: its controller has integral action or a
force feed-forward.  :class:`PositionController` sets, before each ``mj_step``,

    u = r + z + tau_ff / kp,      z' = ki (r - q)                  (1)

``r`` the reference (joint positions), ``z`` the integral of the tracking error
(explicit Euler on the MuJoCo timestep), ``tau_ff`` the joint forces that hold the
block's reaction now, ``J_p^T F + J_r^T M`` with ``(F, M)`` the coupler's
:meth:`~.coupling.CoSimulation.gripper_wrench` (its linearised reaction with
``stiffness=True``) and ``J_p``, ``J_r`` the Jacobians of the gripper body's centre
of mass, where the coupling applies it.  At rest ``q = r`` with either term.

Stability of the integral (one joint of mass ``m``, critical damping
``kv = 2 sqrt(kp m)``, load stiffness ``k >= 0``; Routh on
``m s^3 + kv s^2 + (kp + k) s + kp ki``):

    ki < kv (kp + k) / (m kp),   at least  2 sqrt(kp / m)          (2)

(the bound for a load that gives way, a sliding block): 686 1/s for the gantry's x
carriage (1.7 kg), 2000 1/s for its quill.  A violation shows as the coupling's
period-to-period oscillation warning.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .mjmodel import mujoco_module


class PositionController:
    """Eq. (1) on the ``<position>`` actuators of ``mj_model`` (module docstring).

    Parameters
    ----------
    mj_model : mujoco.MjModel
        Every actuator must be a ``<position>`` actuator on a joint (fixed gain ``kp``,
        affine bias ``-kp q``, gear 1); the reference has one entry per actuator, in its
        joint's units (m or rad).
    ki : float
        Integral gain, 1/s (0: no integral action); bound (2) of the module docstring.
    coupler : CoSimulation, optional
        Feed its gripper wrench forward (``tau_ff`` of eq. (1)); None: no feed-forward.

    Raises
    ------
    InputError
        ``ki`` negative or not finite; an actuator that is not a joint position servo.
    """

    def __init__(self, mj_model, ki: float = 0.0, coupler=None):
        mj = mujoco_module()
        if not (isinstance(ki, (int, float)) and math.isfinite(ki) and ki >= 0):
            raise InputError(f"ki must be a finite number >= 0 (1/s), got {ki!r}")
        m = mj_model
        for a in range(m.nu):
            kp = m.actuator_gainprm[a, 0]
            if (m.actuator_trntype[a] != mj.mjtTrn.mjTRN_JOINT or m.actuator_dyntype[a] != mj.mjtDyn.mjDYN_NONE
                    or m.actuator_gaintype[a] != mj.mjtGain.mjGAIN_FIXED or not kp > 0
                    or m.actuator_biasprm[a, 1] != -kp or m.actuator_gear[a, 0] != 1):
                name = mj.mj_id2name(m, mj.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}"
                raise InputError(f"actuator {name!r} is not a <position> actuator on a joint with gear 1")
        joints = m.actuator_trnid[:, 0]
        self.mj_model, self.ki, self.coupler = m, float(ki), coupler
        self._qadr, self._dof = m.jnt_qposadr[joints], m.jnt_dofadr[joints]
        self._kp = m.actuator_gainprm[:, 0].copy()  # joint force per unit ctrl, N/m or N m/rad
        self.integral = np.zeros(m.nu)  # z of eq. (1), joint units

    def feedforward(self, mj_data) -> np.ndarray:
        """``tau_ff / kp`` (nu,), joint units: the ctrl offset holding the coupler's reaction."""
        c = self.coupler
        if c is None or c._gbody == 0:
            return np.zeros(self.mj_model.nu)
        mj, m = mujoco_module(), self.mj_model
        force, moment = c.gripper_wrench()
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mj.mj_jacBodyCom(m, mj_data, jacp, jacr, c._gbody)
        tau = jacp.T @ force + jacr.T @ moment
        return tau[self._dof] / self._kp

    def __call__(self, mj_data, reference) -> np.ndarray:
        """Set ``mj_data.ctrl`` for the next ``mj_step`` (eq. (1)) and advance the integral; returns the ctrl."""
        r = np.asarray(reference, float)
        mj_data.ctrl[:] = r + self.integral + self.feedforward(mj_data)
        self.integral += self.ki * self.mj_model.opt.timestep * (r - mj_data.qpos[self._qadr])
        return mj_data.ctrl.copy()
