"""The contact law, checked on a step's last iterate before the step is said to have
converged (issue 43: a press was once reported "converged" with the lower face 57-100 um
inside the floor).

At every floor contact node ``i``, with ``r_i = (r_n, r_tx, r_ty)`` its contact force, N,
in the orthotropy frame, ``g_i = Z_i + u_z,i`` its gap, m, and ``M = diag(mu_x, mu_y)``
(paper, eqs. 13-15):

    Signorini       g_i >= 0,   r_n,i >= 0,   r_n,i > 0  =>  g_i = 0
    Coulomb         ||M^-1 r_t,i|| <= r_n,i                  (the elliptic cone)

each to :data:`LAW_TOL`: a gap against ``LAW_TOL L`` (``L`` the block's largest
dimension), a force against ``LAW_TOL R`` (``R`` the largest contact force component of
the step).  The converged steps of the test suite hold it to 1.6e-10 L (gaps) and 5e-16 R
(cone), four orders inside the tolerance; the local solver's own test (its natural-map
residual) is on the scaled problem, and this one is on what the user reads.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

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
    R = float(np.abs(r).max())
    L = max(model.mesh.size)
    if R == 0.0:  # no contact force anywhere: only the gaps can be wrong
        R = np.inf
    f = model.friction
    scaled_t = np.column_stack([_over(r[:, 1], f.mu_x, R), _over(r[:, 2], f.mu_y, R)])
    carrying = r[:, 0] > LAW_TOL * R
    checks = (
        ("penetration", -g / L),
        ("adhesion (negative normal force)", -r[:, 0] / R),
        ("friction force outside the cone", (np.linalg.norm(scaled_t, axis=1) - r[:, 0]) / R),
        ("force at a node off the floor", np.where(carrying, g / L, -np.inf)),
    )
    for what, excess in checks:
        i = int(np.argmax(excess))
        if excess[i] > LAW_TOL:
            return f"{what} at lower-face node {i}: {excess[i]:.3g} (tolerance {LAW_TOL:g} of the block's size or force)"
    return ""


def _over(rt: np.ndarray, mu: float, R: float) -> np.ndarray:
    """``r_t / mu``; for ``mu = 0`` (frictionless along that axis) 0 where ``|r_t| <=
    LAW_TOL R`` and infinite (outside the cone) elsewhere."""
    if mu > 0:
        return rt / mu
    return np.where(np.abs(rt) <= LAW_TOL * R, 0.0, np.inf)


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
