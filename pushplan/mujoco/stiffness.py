"""The block's reaction inside MuJoCo's step, linearised with its condensed
stiffness at the gripper (issue 40 item 5), and the period-to-period oscillation
check of the coupling.

Explicit coupling (``attach(..., stiffness=False)``): the gripper feels the FE
reaction of the last period, constant through the next one.  With an arm of
stiffness ``kp`` at the gripper that settles within a period, the periods are the
fixed-point iteration ``x_{k+1} = x_cmd - k_b x_k / kp`` on the press depth ``x``,
``k_b`` the block's stiffness at the gripper: it converges only when

    k_b < kp                                                   (1)

and otherwise alternates between pressing too deep and separating (the shipped
gantry at kp = 2e5 N/m on a block of E = 8 MPa, 20 x 20 x 10 mm, k_b about
3e5 N/m: 193 N / 0 N every other period).

With ``stiffness=True`` each period's FE step also gives the condensed stiffness
``K = d F_g / d x_g`` (3 x 3, world, N/m: the derivative of the gripper's force
on the block with respect to the gripper's translation, from the converged step's
factor, :func:`fe_contact.rollout_derivatives`), and a passive-force callback
(``mujoco.set_mjcb_passive``) applies on the gripper body at every ``mj_step``

    -(F_g + K (c - c_0))                                       (2)

with ``c`` the upper-face centre carried by the gripper and ``c_0`` its value at
the last ``couple()``: MuJoCo's step sees the reaction change as the arm moves, and
the fixed point (1) is no longer iterated.  MuJoCo integrates (2) explicitly, so
the arm's step must resolve the block's spring; necessary:

    omega * dt < 2,  omega^2 = lambda_max(A K)                 (3)

``A`` (3 x 3, 1/kg) the translational inverse inertia of the arm at the gripper
body (``J M^-1 J^T``), ``dt`` the MuJoCo timestep (the limit of an undamped explicit
spring; the arm's own position gains add to ``K`` and take from the margin: with the
gantry's kp = 2e5 N/m on its 0.2 kg quill and the E = 8 MPa block, omega dt is 1.35
for the block alone, 1.65 with kp, and the run is stable at dt = 1 ms).
``couple()`` checks (3) each period and warns (:class:`CouplingWarning`) when it
fails; it warns too when the gripper force alternates period to period by more than
:data:`OSCILLATION` of its size three times in a row, whatever the mode.  The moment
on the gripper stays the period's (no rotational stiffness).  An arm whose servo is
P or PD only rests off its command by its load over its gain; :mod:`.arm` brings it
to its command (integral action, or this reaction fed forward).
"""

from __future__ import annotations

import warnings

import numpy as np

from .mjmodel import mujoco_module

OSCILLATION = 0.01
"""Relative size of a period-to-period change of the gripper force that counts as an oscillation."""
OMEGA_DT_MAX = 2.0
"""Bound of condition (3): an undamped explicit spring's stability limit."""


class CouplingWarning(UserWarning):
    """The coupling's stability condition fails, or its gripper force oscillates."""


def oscillates(forces) -> bool:
    """Whether the last four gripper forces (N) alternate: three consecutive changes,
    each reversing the previous one and larger than :data:`OSCILLATION` of the largest force."""
    if len(forces) < 4:
        return False
    f = np.asarray(forces[-4:], float)
    steps = np.diff(f, axis=0)
    scale = np.linalg.norm(f, axis=1).max()
    return bool(scale > 0 and all(steps[i] @ steps[i + 1] < 0 for i in range(2))
                and (np.linalg.norm(steps, axis=1) > OSCILLATION * scale).all())


def inverse_inertia(mj_model, mj_data, body: int) -> np.ndarray:
    """``A = J M^-1 J^T`` (3, 3), 1/kg: translational inverse inertia at ``body``'s centre of mass."""
    mj = mujoco_module()
    jacp = np.zeros((3, mj_model.nv))
    mj.mj_jacBodyCom(mj_model, mj_data, jacp, None, body)
    out = np.zeros((3, mj_model.nv))
    mj.mj_solveM(mj_model, mj_data, out, jacp)
    return jacp @ out.T


def omega_dt(mj_model, mj_data, body: int, stiffness: np.ndarray) -> float:
    """``omega * dt`` of condition (3) for the world stiffness (3, 3), N/m."""
    eig = np.linalg.eigvals(inverse_inertia(mj_model, mj_data, body) @ stiffness)
    return float(np.sqrt(max(eig.real.max(), 0.0)) * mj_model.opt.timestep)


class LinearisedReaction:
    """Condition (2) applied by MuJoCo's passive-force callback for one coupler.

    MuJoCo has one passive callback per process: the last coupler made with
    ``stiffness=True`` owns it; :meth:`close` gives it back.
    """

    def __init__(self, coupler):
        self.coupler = coupler
        self.force = np.zeros(3)  # N, world: gripper on the block at c0
        self.moment = np.zeros(3)  # N m: about the gripper body's CoM
        self.centre = None  # c0
        self.stiffness = np.zeros((3, 3))  # N/m, world
        self._previous = mujoco_module().get_mjcb_passive()
        mujoco_module().set_mjcb_passive(self)

    def set(self, force, moment, centre, stiffness) -> None:
        self.force, self.moment = np.asarray(force, float), np.asarray(moment, float)
        self.centre, self.stiffness = np.asarray(centre, float).copy(), np.asarray(stiffness, float)

    def __call__(self, m, d) -> None:
        c = self.coupler
        if d is not c.mj_data or self.centre is None or c._gbody == 0:
            return
        force, moment = self.wrench()
        mujoco_module().mj_applyFT(m, d, -force, -moment, d.xipos[c._gbody].copy(), c._gbody, d.qfrc_passive)

    def wrench(self) -> tuple[np.ndarray, np.ndarray]:
        """``(F_g + K (c - c_0), M)`` of eq. (2) at the gripper's pose now (world, N, N m)."""
        if self.centre is None:
            return self.force, self.moment
        centre, _ = self.coupler.drive_pose()
        return self.force + self.stiffness @ (centre - self.centre), self.moment

    def close(self) -> None:
        mujoco_module().set_mjcb_passive(self._previous)


def warn(message: str) -> None:
    warnings.warn(CouplingWarning(message), stacklevel=3)
