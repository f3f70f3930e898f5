"""Observed order, Richardson extrapolation and the grid convergence index of a
quantity computed on three meshes.

The procedure of Celik, Ghia, Roache, Freitas, Coleman, Raad, "Procedure for
estimation and reporting of uncertainty due to discretization in CFD applications",
J. Fluids Eng. 130 (2008) 078001, which allows refinement ratios that differ between
the two pairs.  Meshes 1 (finest), 2, 3 (coarsest) with representative cell sizes
``h1 < h2 < h3`` and values ``phi1, phi2, phi3``:

    r21 = h2 / h1,  r32 = h3 / h2,  e21 = phi2 - phi1,  e32 = phi3 - phi2,  s = sign(e32 / e21)
    p = | ln|e32 / e21| + ln((r21^p - s) / (r32^p - s)) | / ln r21          (fixed point in p)
    phi_ext = (r21^p phi1 - phi2) / (r21^p - 1)
    GCI21 = Fs |e21 / phi1| / (r21^p - 1),  Fs = 1.25                       (Roache's safety factor)

For ``phi = a + b h^p`` the order and the extrapolation are exact.  A sequence whose
differences change sign (``s < 0``) oscillates, and one whose differences grow as the
mesh is refined is not in the asymptotic range: for either, no order and no
extrapolation are reported, rather than ones forced through the formula.

An observed order far from the discretisation's formal one is the other sign of a
study outside the asymptotic range (Roache, *Verification and Validation in
Computational Science and Engineering*, 1998, sect. 5.10; Celik et al. (2008) ask for
the observed order to be reported beside the formal): with ``order_range`` given, an
order outside it is reported with its note, but no extrapolated value and no GCI band.
A coarse start of the soft-block push (2, 4, 8 elements per side) observes orders of
3.0-3.6 on a second-order element, and the 24 x 24 x 12 values fall 1.5-8.9 bands
outside what its GCI would state (issue 43).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SAFETY_FACTOR = 1.25
ORDER_TOL = 1e-14  # relative change of p that ends the fixed point
ORDER_MAX_ITER = 200
FLAT_TOL = 1e-12  # differences below this, relative to |phi1|, count as converged exactly


@dataclass(frozen=True)
class Extrapolation:
    """Result of the three-mesh procedure for one quantity.

    ``order``, ``value`` and ``gci`` are None when ``monotone`` is false or the
    differences vanish; ``gci`` is relative to ``|phi1|`` (a fraction) and
    ``gci_abs`` the same in the quantity's unit.
    """

    monotone: bool
    order: float | None
    value: float | None
    gci: float | None
    gci_abs: float | None
    note: str = ""

    def to_dict(self) -> dict:
        return {"monotone": self.monotone, "order": self.order, "value": self.value, "gci": self.gci,
                "gci_abs": self.gci_abs, "note": self.note}


def observed_order(r21: float, r32: float, e21: float, e32: float) -> float | None:
    """The order ``p`` of Celik et al. (2008) eq. (3a-c) for a monotone sequence
    (``s = 1``), or None when no ``p > 0`` fits: differences that do not shrink on
    refinement.  The fixed point is iterated without the outer absolute value of
    eq. (3a), which would turn such a sequence into a spurious positive order."""
    log_ratio = math.log(abs(e32 / e21))
    p = max(log_ratio / math.log(r21), 0.5)  # the constant-ratio value as the start
    for _ in range(ORDER_MAX_ITER):
        new = (log_ratio + math.log((r21**p - 1.0) / (r32**p - 1.0))) / math.log(r21)
        if new <= 0:
            return None
        if abs(new - p) <= ORDER_TOL * new:
            return new
        p = new
    return None


def extrapolate(h, phi, order_range: tuple[float, float] | None = None) -> Extrapolation:
    """The procedure on the three finest of ``h`` / ``phi`` (any order of levels).

    Parameters
    ----------
    h : (n,) array_like, n >= 3
        Representative cell sizes of the meshes.
    phi : (n,) array_like
        The quantity on each mesh.
    order_range : (low, high), optional
        Observed orders accepted as asymptotic (module docstring); outside it the
        order is reported with a note, without value and GCI.
    """
    h, phi = np.asarray(h, float), np.asarray(phi, float)
    if h.shape != phi.shape or h.size < 3 or not np.all(np.isfinite(phi)):
        raise ValueError(f"need three or more finite values on as many meshes, got h {h}, phi {phi}")
    order = np.argsort(h)[:3]
    (h1, h2, h3), (p1, p2, p3) = h[order], phi[order]
    e21, e32 = p2 - p1, p3 - p2
    scale = max(abs(p1), abs(p2), abs(p3))
    if abs(e21) <= FLAT_TOL * scale and abs(e32) <= FLAT_TOL * scale:
        return Extrapolation(True, None, float(p1), 0.0, 0.0, "the same value on the three finest meshes")
    if e21 * e32 <= 0:
        return Extrapolation(False, None, None, None, None,
                             "oscillating (the differences change sign): no order, no extrapolation")
    p = observed_order(h2 / h1, h3 / h2, e21, e32)
    if p is None:
        return Extrapolation(True, None, None, None, None,
                             "the differences do not shrink with refinement: not in the asymptotic range")
    if order_range is not None and not order_range[0] <= p <= order_range[1]:
        return Extrapolation(True, float(p), None, None, None,
                             f"observed order {p:.2f} far from the element's (accepted {order_range[0]:g} to "
                             f"{order_range[1]:g}): not in the asymptotic range, no extrapolation and no GCI band")
    rp = (h2 / h1) ** p
    value = (rp * p1 - p2) / (rp - 1.0)
    gci_abs = SAFETY_FACTOR * abs(e21) / (rp - 1.0)
    gci = float(gci_abs / abs(p1)) if p1 != 0 else None
    return Extrapolation(True, float(p), float(value), gci, float(gci_abs))
