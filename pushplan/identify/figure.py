"""The identified friction ellipse against the truth, with its uncertainty.

The friction limit along a slip direction at ``phi`` from world x is the radius of the
ellipse with semi-axes ``mu_x``, ``mu_y`` rotated by ``angle``:

    r(phi) = (cos^2(phi - angle) / mu_x^2 + sin^2(phi - angle) / mu_y^2)^(-1/2).

The band is the 2.5-97.5 % range of ``r(phi)`` over parameter samples drawn from the
Gaussian of the estimate and its Gauss-Newton covariance (a parameter without a finite
standard deviation is drawn with one equal to its value and marked not identifiable).
"""

from __future__ import annotations

import math

import numpy as np

SAMPLES = 2000


def radius(mu_x, mu_y, angle_deg, phi) -> np.ndarray:
    """``r(phi)`` for arrays of parameters (broadcast against ``phi``)."""
    d = phi - np.radians(angle_deg)
    return 1.0 / np.sqrt(np.cos(d) ** 2 / mu_x**2 + np.sin(d) ** 2 / mu_y**2)


def _samples(doc: dict, rng) -> np.ndarray:
    names = ("mu_x", "mu_y", "angle_deg")
    p = doc["parameters"]
    est = np.array([p[k]["estimate"] for k in names])
    sig = np.array([p[k]["sigma"] if p[k]["sigma"] is not None else abs(p[k]["estimate"]) for k in names])
    corr = np.array([[np.nan if v is None else v for v in row] for row in doc["correlation"]])[:3, :3]
    corr = np.where(np.isfinite(corr), corr, np.eye(3))
    draws = rng.multivariate_normal(est, corr * np.outer(sig, sig), SAMPLES, check_valid="ignore")
    draws[:, :2] = np.abs(draws[:, :2])
    return draws


def ellipse_figure(cases, truth: dict, path) -> None:
    """One panel per ``(title, identified.json document)`` of ``cases``; ``truth`` holds
    ``mu_x``, ``mu_y``, ``angle_deg``; written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    phi = np.linspace(0.0, 2 * math.pi, 361)
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 4.4), squeeze=False, sharex=True, sharey=True)
    for ax, (title, doc) in zip(axes[0], cases, strict=True):
        draws = _samples(doc, rng)
        r = radius(draws[:, :1], draws[:, 1:2], draws[:, 2:3], phi[None, :])
        lo, hi = np.percentile(r, [2.5, 97.5], axis=0)
        p = doc["parameters"]
        re = radius(p["mu_x"]["estimate"], p["mu_y"]["estimate"], p["angle_deg"]["estimate"], phi)
        rt = radius(truth["mu_x"], truth["mu_y"], truth["angle_deg"], phi)
        c, s = np.cos(phi), np.sin(phi)
        ax.fill(np.r_[hi * c, lo[::-1] * c[::-1]], np.r_[hi * s, lo[::-1] * s[::-1]], color="tab:blue", alpha=0.25,
                lw=0, label="95 % band")
        ax.plot(rt * c, rt * s, "k-", lw=1.5, label="truth")
        ax.plot(re * c, re * s, "--", color="tab:blue", lw=1.5, label="identified")
        text = "\n".join(f"{k} = {p[k]['estimate']:.4g} ± {p[k]['sigma']:.2g}" if p[k]["sigma"] is not None
                         else f"{k} = {p[k]['estimate']:.4g} ± inf" for k in ("mu_x", "mu_y", "angle_deg"))
        ax.text(0.03, 0.97, text + f"\ntruth {truth['mu_x']:g}, {truth['mu_y']:g}, {truth['angle_deg']:g}",
                transform=ax.transAxes, va="top", fontsize=7, family="monospace")
        flagged = [k for k in ("mu_x", "mu_y", "angle_deg") if not p[k]["identifiable"]]
        ax.set_title(title + (f"\nnot identifiable: {', '.join(flagged)}" if flagged else ""), fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("friction limit, x")
        ax.set_ylabel("friction limit, y")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
