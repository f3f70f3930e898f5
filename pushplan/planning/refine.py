"""The FE correction step with the exact gradient (issue 30 item 4): a Gauss-Newton
step on the FE model from the commands of the last rollout.

With ``r = p(u) - x*`` the FE final-pose miss of commands ``u`` and ``J = dp/du`` its
exact Jacobian (implicit function theorem through the converged steps,
:func:`fe_contact.rollout_derivatives`), the step minimises the planning NLP's own
objective (:mod:`.nlp`) with the FE pose linearised at ``u``:

    min_d  |W^(1/2) (r + J d)|^2 + (u + d)^T E (u + d),
    W = diag(1/tol^2, 1/tol^2, 1/yaw_tol^2),  E = diag(w / (m b_c^2)),

``b_c`` the step bound of component c (``max_step``, ``max_dtheta``), ``w`` the effort
weight, m the number of commands: the least-squares solution of the stacked system
``[W^(1/2) J; E^(1/2)] d = -[W^(1/2) r; E^(1/2) u]``.  Without a yaw target the yaw row
and the ``dtheta`` columns are left out (``dtheta = 0``).  The bounds are not in the
step: a step that would leave them (:meth:`PlanSpec.step_excess`, the bounds every
command is held to, with their slack ``STEP_SLACK``) is refused (None) and the caller
re-solves the NLP with the modifier instead.  Near the solution the step converges
quadratically, where modifier adaptation converges linearly at the rate of the reduced
model's gradient error (Marchetti et al. 2016, first-order modifiers: the same fixed point).
"""

from __future__ import annotations

import numpy as np

from fe_contact import wrap_angle

from ..config.plan import PlanSpec


def gauss_newton_commands(commands: np.ndarray, final: np.ndarray, jacobian: np.ndarray,
                          spec: PlanSpec) -> np.ndarray | None:
    """The refined commands (m, 3) ``(dx, dy, dtheta)`` (m, rad), or None where they
    would leave the step bounds (:meth:`PlanSpec.step_excess`).

    Parameters
    ----------
    commands : (m, 3)
        The commands rolled out, m and rad.
    final : (3,)
        Their FE final lower-face pose ``(x, y, yaw)``, m and rad.
    jacobian : (3, m, 3)
        ``d final[i] / d commands[k, c]``, m/m, m/rad, rad/m, rad/rad.
    """
    u = np.asarray(commands, float)
    m = len(u)
    cols = [0, 1, 2] if spec.yaw_targeted else [0, 1]
    rows = cols
    r = np.asarray(final, float) - np.asarray(spec.target, float)
    r[2] = float(wrap_angle(r[2]))
    w = np.sqrt(np.array([1 / spec.tolerance**2, 1 / spec.tolerance**2, 1 / spec.yaw_tolerance**2]))[rows]
    bounds = np.array([spec.max_step, spec.max_step, spec.max_dtheta])[cols]
    e = np.sqrt(spec.effort_weight / m) / np.tile(bounds, m)  # E^(1/2), per (k, c) step-major
    J = jacobian[rows][:, :, cols].reshape(len(rows), m * len(cols))
    x = u[:, cols].ravel()
    A = np.vstack([w[:, None] * J, np.diag(e)])
    b = -np.concatenate([w * r[rows], e * x])
    d = np.linalg.lstsq(A, b, rcond=None)[0]
    refined = u.copy()
    refined[:, cols] = (x + d).reshape(m, len(cols))
    return None if spec.step_excess(refined) is not None else refined
