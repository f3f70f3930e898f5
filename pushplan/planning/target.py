"""The planning target measured: the naive baseline push, the error of a final
lower-face pose against the target and the tolerance test."""

from __future__ import annotations

import math

import numpy as np

from fe_contact import wrap_angle

from ..config.plan import PlanSpec


def naive_commands(spec: PlanSpec) -> np.ndarray:
    """The baseline: the upper face moved straight towards the target pose in K equal
    steps, (K, 3), each within the step bounds (``max_step``, ``max_dtheta``) the plan
    has: for a target out of reach the baseline goes as far as the robot may, like the plan."""
    step = np.array(spec.target) * np.array([1.0, 1.0, float(spec.yaw_targeted)]) / spec.steps
    length = math.hypot(step[0], step[1])
    if length > spec.max_step:
        step[:2] *= spec.max_step / length
    if spec.yaw_targeted and abs(step[2]) > spec.max_dtheta:
        step[2] = math.copysign(spec.max_dtheta, step[2])
    return np.tile(step, (spec.steps, 1))


def pose_error(pose, spec: PlanSpec) -> tuple[float, float]:
    """Position error (m) and absolute yaw error (rad, 0 without a yaw target) of a
    final lower-face pose ``(x, y, yaw)``."""
    e = np.asarray(pose, float)[:2] - spec.target[:2]
    yaw = abs(float(wrap_angle(pose[2] - spec.target[2]))) if spec.yaw_targeted else 0.0
    return float(np.hypot(*e)), yaw


def within_tolerance(pose, spec: PlanSpec) -> bool:
    """Whether both errors of :func:`pose_error` are within the spec's tolerances."""
    pos, yaw = pose_error(pose, spec)
    return pos <= spec.tolerance and yaw <= spec.yaw_tolerance


def reach_origin(spec: PlanSpec, lag, springback) -> np.ndarray:
    """Where the reach of a plan from a loaded state is measured from (3,) (m, m, rad),
    relative to the lower face there: the pose the block would end at without a push.

    A loaded target: the lower face itself (zeros; the lag is carried along by the pushes).
    A rest target: the rest the state would spring back to, ``s (u - l)``
    (:class:`~.springback.Springback`, ``lag = u - l`` the start's, (3,)); after pushes of
    total ``c`` the rest is about ``l + s lag + c``, so the commands' bound reaches
    ``K max_step`` from there (a bonded lift, ``s = 1``: from the upper face)."""
    if spec.target_state != "rest":
        return np.zeros(3)
    return np.asarray(springback, float) * np.asarray(lag, float)


def reach_message(spec: PlanSpec, origin=(0.0, 0.0, 0.0)) -> str:
    """Why the target is beyond the step bounds from ``origin`` (:func:`reach_origin`),
    or ``""`` when it is reachable."""
    if spec.reachable_from(origin):
        return ""
    d = np.array(spec.target) - np.asarray(origin, float)
    return (f"target {math.hypot(d[0], d[1]) * 1e3:.4g} mm"
            + (f" / {math.degrees(d[2]):.4g} deg" if spec.yaw_targeted else "")
            + f" is beyond reach of {spec.steps} steps of {spec.max_step * 1e3:.4g} mm"
            + (f" / {math.degrees(spec.max_dtheta):.4g} deg" if spec.yaw_targeted else "")
            + "; planning the closest reachable pose")
