"""The heights a release goes to, as functions of the path it has taken, with
their partial derivatives: the one formula of each for the release schedule
(:class:`fe_contact.stepping.release.ReleaseSchedule`) and for the derivatives
of the rest after a release (:mod:`fe_contact.stepping.derivatives`), which
differentiate the release's path as the schedule chose it.
"""

from __future__ import annotations

__all__ = ["pad_lift_rise", "put_down_target"]


def pad_lift_rise(points, loaded: float, depth: float, weight: float, steps: int,
                  grip_floor: float) -> tuple[float, dict]:
    """The next rise of a frictional pad's lift (:meth:`ReleaseSchedule._pad_lift`),
    m, and its partial derivatives (to differentiate the release's path).

    ``points`` are the lift's ``(pad height m, pad load N)`` so far, the last
    the current one ``(h, N)``; ``loaded`` the loaded pad load ``N_0``, N;
    ``depth`` the press depth ``d``, m; ``weight`` ``W``, N.  The rise is
    ``(N - target) / s`` to ``target = max(N - N_0 / steps, q N, f N_0)``
    (``f = min(1/2, grip_floor W / N_0)``, ``q = f^(1 / (steps - 1))``), or
    ``2 N / s`` past the zero once ``N <= f N_0``; ``s`` the secant of the last
    two points' load against height when it is positive, else ``N_0 / d``.
    The partials are keyed ``("h", i)``, ``("n", i)`` (of point ``i``),
    ``"loaded"``, ``"depth"``, ``"weight"``.
    """
    last = len(points) - 1
    h, load = points[last]
    slope, d_slope = loaded / depth, {"loaded": 1.0 / depth, "depth": -loaded / depth**2}  # -dN/dh of the press
    if len(points) >= 2:
        (h1, n1), (h2, n2) = points[-2:]
        if h2 != h1 and (n1 - n2) / (h2 - h1) > 0:
            slope = (n1 - n2) / (h2 - h1)
            d_slope = {("n", last - 1): 1.0 / (h2 - h1), ("n", last): -1.0 / (h2 - h1),
                       ("h", last): -slope / (h2 - h1), ("h", last - 1): slope / (h2 - h1)}
    floor = min(0.5, grip_floor * weight / loaded)
    d_floor = {} if floor == 0.5 else {"weight": floor / weight, "loaded": -floor / loaded}
    if load <= floor * loaded * (1 + 1e-9):  # past the zero: every pad contact opens
        dz, d_rise = 2.0 * load / slope, {("n", last): 2.0}
    else:
        m = max(steps - 1, 1)
        q = floor ** (1.0 / m)
        d_q = {k: v * q / (m * floor) for k, v in d_floor.items()}
        options = [load - loaded / steps, q * load, floor * loaded]
        target = max(options)
        d_target = [{("n", last): 1.0, "loaded": -1.0 / steps},
                    _sum_partials((q, {("n", last): 1.0}), (load, d_q)),
                    _sum_partials((floor, {"loaded": 1.0}), (loaded, d_floor))][options.index(target)]
        dz, d_rise = (load - target) / slope, _sum_partials((1.0, {("n", last): 1.0}), (-1.0, d_target))
    return dz, _sum_partials((1.0 / slope, d_rise), (-dz / slope, d_slope))


def _sum_partials(*terms) -> dict:
    """``sum c d`` of partial-derivative dicts ``d`` with coefficients ``c``."""
    out: dict = {}
    for c, d in terms:
        for k, v in d.items():
            out[k] = out.get(k, 0.0) + c * v
    return out


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
