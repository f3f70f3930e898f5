"""The heights a release goes to, as functions of the path it has taken, with
their partial derivatives: the one formula of each for the release schedule
(:class:`fe_contact.stepping.release.ReleaseSchedule`) and for the derivatives
of the rest after a release (:mod:`fe_contact.stepping.derivatives`), which
differentiate the release's path as the schedule chose it.
"""

from __future__ import annotations

__all__ = ["put_down_target"]


def put_down_target(points, weight: float, axial_stiffness: float, slow: bool,
                    lift_tol: float) -> tuple[float, dict]:
    """The next height of a put-down (:meth:`ReleaseSchedule._put_down`), m,
    and its partial derivatives (to differentiate the release's path,
    :mod:`fe_contact.stepping.derivatives`).

    ``points`` are the put-down's ``(plate height m, vertical force N,
    touching)`` so far, the last the current one; ``weight`` ``W`` (N),
    ``axial_stiffness`` ``k = E A / H`` (N/m); ``slow`` bisects.  The partials
    are keyed ``("h", i)``, ``("f", i)`` (of point ``i``), ``"weight"``,
    ``"stiffness"``: the bracket's regula falsi ``h_lo - f_lo (h_hi - h_lo) /
    (f_hi - f_lo)``, its bisection, the step ``h_lo - f_lo / k`` below a flat
    (off the floor) end, or before the first push ``min(-W / (2 k), h - W / k)``.
    """
    W, k = weight, axial_stiffness
    pulls = [i for i, (_, f, _) in enumerate(points) if f > 0]
    pushes = [i for i, (_, f, _) in enumerate(points) if f < 0]
    if not pushes:  # not down to the floor's load yet
        last = len(points) - 1
        if -W / (2.0 * k) <= points[last][0] - W / k:
            return -W / (2.0 * k), {"weight": -1.0 / (2.0 * k), "stiffness": W / (2.0 * k**2)}
        return points[last][0] - W / k, {("h", last): 1.0, "weight": -1.0 / k, "stiffness": W / k**2}
    hi = min(pulls, key=lambda i: points[i][:2])
    lo = max(pushes, key=lambda i: points[i][:2])
    (h_hi, f_hi, _), (h_lo, f_lo, _) = points[hi], points[lo]
    middle = 0.5 * (h_lo + h_hi), {("h", lo): 0.5, ("h", hi): 0.5}
    if slow:
        return middle
    if f_hi >= W * (1.0 - lift_tol):  # off the floor up there: F is flat, step with E A / H
        target = h_lo - f_lo / k
        return (target, {("h", lo): 1.0, ("f", lo): -1.0 / k, "stiffness": f_lo / k**2}) if target < h_hi else middle
    d, dh = f_hi - f_lo, h_hi - h_lo
    return h_lo - f_lo * dh / d, {("h", lo): 1.0 + f_lo / d, ("h", hi): -f_lo / d, ("f", lo): -dh * f_hi / d**2,
                                  ("f", hi): f_lo * dh / d**2}
