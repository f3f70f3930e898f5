"""Where a frictional pad's release (load control, issue 39) makes its error in the
load steps: the local error of each of ``n`` load steps against a ``reference``-step
release, and the contacts that change state (open / stick / slip) inside each step.

The block of benchmarks/release_refinement.py: rubber 40 x 30 x 20 mm (3 x 2 x 2 hex8,
quadrature 2, E 2 MPa, nu 0.45, 1000 kg/m^3), floor 0.6 / 0.2 at 20 deg, pressed 0.4 mm,
pushed twice (0.6, 0.2) mm and 1 deg, pad ``ratio`` x the floor's friction.  The
reference release takes ``reference`` load steps of the same schedule (its loads
include every ``n``-step load: ``reference`` a multiple of ``n``).  For load step ``k``
of ``n``: one step from the reference's state at ``P_{k-1}`` to ``P_k`` against the
reference's state at ``P_k``, as the lower face's centroid distance in units of the
loaded lag (the local error), and the number of contacts (floor and pad) whose
state changes between the reference's steps inside it.  Also the rest after ``n``,
``4 n`` load steps (backward Euler and the midpoint rule) against the reference's, in units
of the lag (the global error).  Every step here is backward Euler (``Release.scheme``).

    python benchmarks/release_error_source.py [--n 16] [--reference 256] [--ratios 0.01 1 100]

Writes ``benchmarks/results/release_error_source.json``.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from _common import write_results
from fe_contact import Command, Friction, Material, Model, PadLoad, Release, block_mesh, release_to_rest, run, step
from fe_contact.stepping.release import pad_load_schedule
from fe_contact.stepping.sequence import StepSequence

FLOOR = (0.6, 0.2, math.radians(20.0))
PUSH = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))


def contact_state(model: Model, reaction: np.ndarray) -> np.ndarray:
    """0 open, 1 stick, 2 slip (force on its cone to 1e-6) for every contact, floor then pad."""
    mu = np.column_stack([model.contacts.mu_x, model.contacts.mu_y])
    opened = reaction[:, 0] <= 1e-9 * np.abs(reaction).max()
    on_cone = np.hypot(reaction[:, 1] / mu[:, 0], reaction[:, 2] / mu[:, 1]) >= (1 - 1e-6) * reaction[:, 0]
    return np.where(opened, 0, np.where(on_cone, 2, 1))


def analyse(ratio: float, n: int, reference: int) -> dict:
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*FLOOR),
              quadrature=2, pad=Friction(FLOOR[0] * ratio, FLOOR[1] * ratio, FLOOR[2]))
    state, pushes = run(m, [Command(dz=-4e-4), PUSH, PUSH])
    lag = float(np.linalg.norm(pushes[-1].lag))
    sequence = StepSequence(m, (), state, release=Release("lift", reference, max_steps=10 * reference,
                                                          scheme="backward_euler"),
                            loaded=pushes[-1], consume_start=False)
    states, reports = [state], [pushes[-1]]
    for s, r in sequence:
        states.append(s)
        reports.append(r)
    k = reference // n
    steps = []
    loads = [-float(r.upper_force[2]) for r in reports]
    for i in range(n):
        if (i + 1) * k >= len(states) or i < n - 1 and not math.isclose(
                loads[(i + 1) * k], pad_load_schedule(loads[0], m.weight, (i + 1) * k, reference)[0], rel_tol=1e-6):
            steps.append(None)  # the reference skipped this load (a step past a jump of the load)
            continue
        start, end = states[i * k], states[(i + 1) * k]
        load = 0.0 if i == n - 1 else max(0.0, loads[(i + 1) * k])
        _, one = step(m, start, PadLoad(load))
        ref_end = reports[(i + 1) * k].lower_centroid[:2]
        changes = sum(int((contact_state(m, a.reaction) != contact_state(m, b.reaction)).sum())
                      for a, b in zip(states[i * k:(i + 1) * k], states[i * k + 1:(i + 1) * k + 1], strict=True))
        steps.append({"load": load, "local_error": float(np.linalg.norm(one.lower_centroid[:2] - ref_end) / lag),
                      "state_changes": changes, "slipping": int((contact_state(m, end.reaction) == 2).sum()),
                      "newton": one.newton_iterations})
    rests = {}
    for scheme in ("backward_euler", "midpoint"):
        for steps_ in (n, 4 * n):
            _, release, _ = release_to_rest(m, state, Release("lift", steps_, max_steps=10 * steps_ + 100,
                                                              scheme=scheme), pushes[-1])
            rests[f"{scheme}_{steps_}"] = release[-1].lower_centroid[:2]
    ref_rest = reports[-1].lower_centroid[:2]
    return {"ratio": ratio, "n": n, "reference": reference, "lag": lag, "contacts": int(m.n_contacts), "steps": steps,
            "sum_local_error": float(sum(s["local_error"] for s in steps if s)),
            "global_error": {str(s): float(np.linalg.norm(r - ref_rest) / lag) for s, r in rests.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=16)
    parser.add_argument("--reference", type=int, default=256)
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.01, 1.0, 100.0])
    args = parser.parse_args()
    rows = []
    for ratio in args.ratios:
        row = analyse(ratio, args.n, args.reference)
        rows.append(row)
        print(f"pad {ratio} x floor: lag {row['lag']:.3g} m, global error vs {args.reference} steps "
              f"{row['global_error']}, sum of local errors {row['sum_local_error']:.4f}")
        for i, s in enumerate(row["steps"]):
            if s is None:
                print(f"  step {i + 1:2d}  (the reference skipped its load: a jump)")
                continue
            print(f"  step {i + 1:2d}  P {s['load']:9.3g} N  local error {s['local_error']:.5f}  "
                  f"state changes {s['state_changes']:3d}  slipping {s['slipping']:2d}/{row['contacts']}", flush=True)
    print("wrote", write_results("release_error_source", {"floor": FLOOR[:2], "rows": rows}))


if __name__ == "__main__":
    main()
