"""The rest pose after a physical release against the pad / floor friction ratio
(issue 28): a rubber block with weight (40 x 30 x 20 mm, 3 x 2 x 2 elements, E 2 MPa,
nu 0.45, 1000 kg/m^3; floor mu 0.6 / 0.2 at 20 deg) pressed 0.4 mm and pushed twice
(0.6, 0.2 mm, 1 deg) by a frictional pad whose friction is ``ratio`` times the
floor's, then released by lifting the pad until every pad contact is open.  The
bonded pad (the lift) and the loaded pose are the two bounds.

    python benchmarks/release_pad.py [--steps 32] [--ratios 0.01 0.1 ...]

Writes ``benchmarks/results/release_pad.json`` and ``docs/figures/release_pad.png``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, Release, block_mesh, release_to_rest, run

ROOT = Path(__file__).resolve().parents[1]
FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
RATIOS = (0.01, 0.1, 0.3, 0.5, 1.0, 2.0, 5.0, 100.0)


def release(ratio, steps: int) -> dict:
    """Loaded and rest lower-face centroid (m) of the block with a pad of ``ratio``
    times the floor's friction (None: bonded), released in ``steps``."""
    pad = None if ratio is None else Friction(FLOOR[0] * ratio, FLOOR[1] * ratio, FLOOR[2])
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=pad)
    t0 = time.perf_counter()
    state, reports = run(m, [Command(dz=-4e-4), PUSH, PUSH])
    _, rel, rest = release_to_rest(m, state, Release("lift", steps, max_steps=2000), reports[-1])
    return {"ratio": ratio, "loaded": reports[-1].lower_centroid[:2].tolist(),
            "upper": reports[-1].upper_centroid[:2].tolist(), "rest": rel[-1].lower_centroid[:2].tolist(),
            "lag": float(np.linalg.norm(reports[-1].lag)), "status": rest.status, "release_steps": len(rel),
            "max_newton_iterations": max(r.newton_iterations for r in rel), "seconds": time.perf_counter() - t0}


def figure(rows, bonded, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = [r["ratio"] for r in rows]
    commanded = np.array([1.2e-3, 4e-4])
    direction = commanded / np.linalg.norm(commanded)
    along = lambda p: 1e3 * float(np.asarray(p) @ direction)  # noqa: E731  mm along the push
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.semilogx(ratios, [along(r["rest"]) for r in rows], "o-", label="rest pose, frictional pad")
    ax.semilogx(ratios, [along(r["loaded"]) for r in rows], "s--", color="0.5", label="loaded pose, same pad")
    ax.axhline(along(bonded["rest"]), color="C2", label="bonded pad (lift): under the upper face")
    ax.axhline(along(bonded["loaded"]), color="C3", ls=":", label="loaded pose, bonded pad")
    ax.set_xlabel("pad friction / floor friction")
    ax.set_ylabel("lower-face centroid along the push (mm)")
    ax.set_title("Rest pose after the pad lifts off (rubber block with weight)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=32)
    parser.add_argument("--ratios", type=float, nargs="+", default=RATIOS)
    args = parser.parse_args()
    bonded = release(None, args.steps)
    rows = [release(r, args.steps) for r in args.ratios]
    print(f"{'ratio':>7} {'loaded x,y (mm)':>20} {'rest x,y (mm)':>20} {'lag mm':>8} {'status':>11} {'steps':>5} "
          f"{'max it':>6} {'s':>5}")
    for r in [bonded] + rows:
        print(f"{str(r['ratio']):>7} {r['loaded'][0]*1e3:9.4f},{r['loaded'][1]*1e3:9.4f} "
              f"{r['rest'][0]*1e3:9.4f},{r['rest'][1]*1e3:9.4f} {r['lag']*1e3:8.4f} {r['status']:>11} "
              f"{r['release_steps']:5d} {r['max_newton_iterations']:6d} {r['seconds']:5.1f}")
    figure(rows, bonded, ROOT / "docs" / "figures" / "release_pad.png")
    print("wrote", write_results("release_pad", {"steps": args.steps, "bonded": bonded, "rows": rows}))


if __name__ == "__main__":
    main()
