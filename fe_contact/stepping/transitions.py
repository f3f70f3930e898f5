"""Where a rollout's derivative does not exist: a contact at a transition of
the contact law at the end of a step (issue 39 item 4).

The derivatives of :mod:`fe_contact.stepping.derivatives` linearise each
contact on the branch it ended on (:mod:`fe_contact.contact.law_jacobian`).
Each branch holds while a margin stays positive:

=========  ==============================================  ===========================
branch     margin ``m`` (stays >= 0 on the branch)           its derivative ``dm``
=========  ==============================================  ===========================
separated  the gap ``u_n``, m                                ``du_n``
closed     the normal force ``r_n``, N (stick and slip)      ``dr_n``
stick      ``phi = r_n - ||M^-1 r_t||``, N (inside the cone)  ``d phi``
slip       the slip increment ``||u_t||``, m                 ``u_t . du_t / ||u_t||``
=========  ==============================================  ===========================

``M = diag(mu_x, mu_y)``.  Along input ``j`` (typical size ``s_j``: a
command's largest translation or turn, a parameter's value) the branch holds
for input changes up to ``m / |dm_j|``; where that is at most

    m <= TRANSITION_TOL s_j |dm_j|,

an input change of ``TRANSITION_TOL`` of its typical size moves the contact
to another branch: the contact is at a transition, and the outputs from that
step on have no derivative along ``j`` (only one-sided ones, which differ).
Those entries are NaN in the result and the transition is reported
(:class:`Transition`); the other inputs keep their derivatives.  A margin
exactly zero with ``dm_j = 0`` (a contact that stays on the border to first
order, e.g. a block at rest stepped by a null command) is not a transition.

The cone's margin derivative is a difference, ``d phi = dr_n - d||M^-1 r_t||``,
and on the cone's edge a contact can stay on to first order: one that slipped
in a step and does not move in the next (the release's steps after the pad
opened move nothing), whose force the slip rule kept on the cone, ``d phi =
0``.  Computed, the two terms differ by the rounding of the solves and by the
tolerance of the converged state they are linearised at, which the test above
would call a transition of a contact that sits exactly on its edge (``phi =
0``).  Along input ``j`` the one-sided derivatives of the outputs differ by the
slip that one side takes, driven by the force ``d phi_j`` pushes past the cone,
against derivatives driven by the contact forces' own ``dr_c,j``; so, with

    D_j = max_c (|dr_n,c,j| + |d||M^-1 r_t||_c,j|),     N,

the largest force derivative along ``j`` over the step's contacts ``c``, a
cancellation to

    |d phi_j| <= CANCELLATION_TOL D_j

is ``d phi_j = 0``: no transition along ``j``, the derivative exact to about
that fraction.  Measured (the settle steps after a pad opened; 2 x 2 x 1, 3 x 3 x 1
and 3 x 3 x 2 blocks): ``|d phi_j| / D_j`` at most 4e-9 at ``newton_tol`` 1e-13,
2.3e-8 at the default 1e-10 (up to 1.6e-6 of the contact's own two terms, along
the floor's angle, which barely moves it: the contact's own terms are no scale).  A contact that a push moves off its cone's edge (``|d
phi_j| / D_j`` of order one) stays a transition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import NodeStatus

__all__ = ["CANCELLATION_TOL", "TRANSITION_TOL", "Transition", "flipping_inputs", "margins", "summary"]

TRANSITION_TOL = 1e-6
"""A contact is at a transition when an input change of this fraction of the input's typical size takes it to
another branch of the contact law (module docstring)."""

CANCELLATION_TOL = 1e-6
"""The cone margin's derivative along an input is zero where it is at most this fraction of the step's largest
contact force derivative along it (module docstring; measured noise 2.3e-8 at ``newton_tol`` 1e-10)."""

KINDS = ("gap", "normal force", "cone", "slip")


@dataclass(frozen=True)
class Transition:
    """A contact at a transition at the end of a step.

    Attributes
    ----------
    step : int
        1-based index of the step in the rollout (a release's steps follow the commands).
    contact : int
        Index of the contact (the floor's, then a frictional pad's).
    kind : str
        The margin that vanishes: ``"gap"`` (a separated contact touching),
        ``"normal force"`` (a closed contact with no force), ``"cone"`` (a
        sticking contact on its cone's edge), ``"slip"`` (a slipping contact
        that barely slips).
    margin : float
        The margin over ``s_j |dm_j|`` of the input that moves it most: the
        fraction of that input's typical size that changes the branch.
    inputs : tuple of int
        The input columns along which the branch changes.
    """

    step: int
    contact: int
    kind: str
    margin: float
    inputs: tuple



def margins(status: np.ndarray, r: np.ndarray, u: np.ndarray, mu_x, mu_y, dr: np.ndarray, du: np.ndarray,
            dmu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each contact's smallest branch margin (module docstring): ``(m (n, 2),
    dm (n, 2, J), kind (n, 2))``, two margins per contact (the normal one and,
    for a closed contact, the tangential one; the second is ``inf`` for a
    separated contact).

    ``r`` (n, 3) local forces, N; ``u`` (n, 3) local gap and tangential
    increments, m; ``dr``, ``du`` (n, 3, J) their derivatives; ``dmu`` (n, 2, J)
    the friction coefficients' (zero where an input does not move them)."""
    n, J = r.shape[0], dr.shape[2]
    mu = np.stack(np.broadcast_arrays(np.asarray(mu_x, float), np.asarray(mu_y, float)), axis=-1)
    mu = np.broadcast_to(mu, (n, 2))
    m, dm = np.full((n, 2), np.inf), np.zeros((n, 2, J))
    kind = np.zeros((n, 2), dtype=int)
    separated, slip = status == NodeStatus.SEPARATED, status == NodeStatus.SLIP
    stick = ~separated & ~slip
    m[:, 0] = np.where(separated, u[:, 0], r[:, 0])
    dm[:, 0] = np.where(separated[:, None], du[:, 0], dr[:, 0])
    kind[:, 0] = np.where(separated, 0, 1)
    v = r[:, 1:] / mu  # M^-1 r_t
    nv = np.linalg.norm(v, axis=1)
    safe = np.where(nv > 0, nv, 1.0)
    d_nv = np.einsum("ci,cik->ck", v / mu / safe[:, None], dr[:, 1:]) \
        - np.einsum("ci,cik->ck", v**2 / mu / safe[:, None], dmu)
    d_nv = np.where(nv[:, None] > 0, d_nv, np.linalg.norm(dr[:, 1:] / mu[:, :, None], axis=1))
    m[stick, 1] = r[stick, 0] - nv[stick]
    d_phi = dr[:, 0] - d_nv
    D = (np.abs(dr[:, 0]) + np.abs(d_nv)).max(axis=0, initial=0.0)  # (J,) the step's force derivatives
    dm[stick, 1] = np.where(np.abs(d_phi) <= CANCELLATION_TOL * D, 0.0, d_phi)[stick]  # cancelled: d phi = 0
    kind[stick, 1] = 2
    s = np.linalg.norm(u[:, 1:], axis=1)
    m[slip, 1] = s[slip]
    dm[slip, 1] = np.einsum("ci,cik->ck", u[slip, 1:] / np.where(s[slip] > 0, s[slip], 1.0)[:, None], du[slip, 1:])
    kind[slip, 1] = 3
    return m, dm, kind


def flipping_inputs(step: int, m: np.ndarray, dm: np.ndarray, kind: np.ndarray, typical: np.ndarray,
                    skip: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    """The input columns (J,) bool along which a contact changes branch
    (``m <= TRANSITION_TOL s_j |dm_j|``, module docstring) and the
    :class:`Transition` of each such contact (``step`` 1-based).  ``typical``
    (J,) the inputs' sizes (0: a column not checked); ``skip`` (n,) bool the
    contacts left out (a frictional pad's, open by construction at zero load)."""
    reach = np.abs(dm) * typical  # (n, 2, J)
    with np.errstate(invalid="ignore"):
        flips = np.abs(m)[:, :, None] <= TRANSITION_TOL * reach
        flips &= reach > 0
    if skip is not None:
        flips[skip] = False
    found = []
    for c, i in zip(*np.nonzero(flips.any(axis=2)), strict=True):
        cols = np.flatnonzero(flips[c, i])
        ratio = float(np.abs(m[c, i]) / reach[c, i, cols].max())
        found.append(Transition(step, int(c), KINDS[kind[c, i]], ratio, tuple(int(j) for j in cols)))
    return flips.any(axis=(0, 1)), found


def summary(transitions, names) -> str:
    """One line per step and kind of transition: how many contacts, the smallest
    margin (the fraction of an input's size that changes a branch), the inputs
    without a derivative (``names`` the column names); "" without transitions."""
    groups: dict = {}
    for t in transitions:
        groups.setdefault((t.step, t.kind), []).append(t)
    lines = []
    for (step, kind), group in groups.items():
        inputs = sorted({j for t in group for j in t.inputs})
        listed = ", ".join(names[j] for j in inputs[:6]) + (", ..." if len(inputs) > 6 else "")
        lines.append(f"step {step}: {len(group)} contact(s) at a transition of the contact law ({kind}: an input "
                     f"change of {min(t.margin for t in group):.2g} of its size changes the branch, at most "
                     f"{TRANSITION_TOL:g} allowed); no derivative along {listed}")
    return "; ".join(lines)
