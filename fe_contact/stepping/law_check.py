"""The contact law, checked on a step's last iterate before the step is said to have
converged (issue 43: a press was once reported "converged" with the lower face 57-100 um
inside the floor).

At every floor contact node ``i``, with ``r_i = (r_n, r_tx, r_ty)`` its contact force, N,
in the orthotropy frame, ``g_i = Z_i + u_z,i`` its gap, m, and ``M = diag(mu_x, mu_y)``
(paper, eqs. 13-15):

    Signorini       g_i >= 0,   r_n,i >= 0,   r_n,i > 0  =>  g_i = 0
    Coulomb         ||M^-1 r_t,i|| <= r_n,i                  (the elliptic cone)

each to :data:`LAW_TOL`: a gap against ``LAW_TOL L`` (``L`` the block's largest
dimension), a force against ``LAW_TOL R`` (``R`` the step's force scale: the largest contact
force component, the gripper's force or the weight, whichever is largest; a lifted block's
floor forces are rounding noise against its weight).  The converged steps of the test suite hold it to 1.6e-10 L (gaps) and 5e-16 R
(cone), four orders inside the tolerance; the local solver's own test (its natural-map
residual) is on the scaled problem, and this one is on what the user reads.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..contact.friction import elliptic_norm
from .model import Model
from .report import Status, StepReport

LAW_TOL = 1e-6
"""Relative tolerance of the contact law on a converged step (gaps / L, forces / R)."""


def law_violation(model: Model, report: StepReport) -> str:
    """What of the contact law the report's floor contacts break, beyond :data:`LAW_TOL`
    ("" when it holds): the worst node and its value relative to the tolerance's scale."""
    r, g = report.reaction_local, report.gap
    if r.size == 0:
        return ""
    R = max(float(np.abs(r).max()), float(np.linalg.norm(report.upper_force)), report.weight)
    L = max(model.mesh.size)
    if R == 0.0:  # no force anywhere: only the gaps can be wrong
        R = np.inf
    f = model.friction
    carrying = r[:, 0] > LAW_TOL * R
    checks = (
        ("penetration", -g / L),
        ("adhesion (negative normal force)", -r[:, 0] / R),
        ("friction force outside the cone", (elliptic_norm(r[:, 1:], f.mu_x, f.mu_y) - r[:, 0]) / R),
        ("force at a node off the floor", np.where(carrying, g / L, -np.inf)),
    )
    for what, excess in checks:
        i = int(np.argmax(excess))
        if excess[i] > LAW_TOL:
            return f"{what} at lower-face node {i}: {excess[i]:.3g} (tolerance {LAW_TOL:g} of the block's size or force)"
    return ""


def checked(model: Model, report: StepReport) -> StepReport:
    """``report``, or, when it says converged and the contact law does not hold, the same
    report with status ``CONTACT_NOT_CONVERGED`` and a message naming the violation."""
    if not report.converged:
        return report
    violation = law_violation(model, report)
    if not violation:
        return report
    return replace(report, status=Status.CONTACT_NOT_CONVERGED,
                   message=f"contact law violated at the end of the step: {violation}")
