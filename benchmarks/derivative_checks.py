"""The rest pose's exact derivatives against central differences through every
release (issue 39 item 4), on the small meshes of the tests: a 20 x 20 x 10 mm
block (2 x 2 x 1 elements, E 2 MPa, nu 0.3; floor mu 0.3 / 0.15 at 0.4 rad),
pressed 0.2 mm and pushed (0.2, 0.1 mm, 0.01 rad), then lifted (3 steps) by

* a rigid frictional pad of mu 2, 0.5, 0.25, 0.15, 0.05 (sticking, mixed, sliding) with the
  default midpoint load steps (differentiated as they run); mu 0.05 also at a tenth of the
  central differences' step (its 3-step rest is on a strongly curved branch: the
  differences' ``h^2`` error) and with 4 load steps; mu 0.15 with backward-Euler steps;
* a compliant gripper (2e3 N/m, 2 N m/rad) with a frictional pad of mu 2, 0.15 and 0.05;
* the bonded pad, rigid and compliant (put down where the plate carries nothing).

Each row: the largest normalised error of :func:`fe_contact.check_derivatives`
(the issue's bound 1e-5), its worst entry, and the smallest margin of a contact
to a transition of the contact law over the rollout's steps
(:mod:`fe_contact.stepping.transitions`: the fraction of an input's size that
would change a contact's branch; the flag's threshold is 1e-6).

    python benchmarks/derivative_checks.py [--cases pad2 ...]

Writes ``benchmarks/results/derivative_checks.json``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import fe_contact.stepping.derivatives as derivatives
import fe_contact.stepping.gripper as gripper
from _common import write_results
from fe_contact import Command, Friction, Gripper, Material, Model, Release, SolverOptions, block_mesh
from fe_contact.stepping.derivative_check import check_derivatives
from fe_contact.stepping.transitions import KINDS

TIGHT = SolverOptions(newton_tol=1e-13, local_tol=1e-14, path_tol=1e-13)  # central differences: the path tight too
SIZE = (0.02, 0.02, 0.01)
PAD_PUSH = [Command(dz=-2e-4), Command(dx=2e-4, dy=1e-4, dtheta=0.01)]
BONDED_PUSH = [Command(dz=-2e-4), Command(dx=3e-4, dy=1e-4, dtheta=0.01)]
COMPLIANT = Gripper(2e3, 2.0)


def _model(density, pad_mu=None, grip=None):
    return Model(block_mesh(SIZE, (2, 2, 1)), Material(2e6, 0.3, density), Friction(0.3, 0.15, 0.4), options=TIGHT,
                 pad=None if pad_mu is None else Friction(pad_mu, 0.8 * pad_mu, 0.3), gripper=grip or Gripper())


LIFT = Release("lift", 3)
CASES = {  # name: (model, commands, central-difference step, parameters, release)
    **{f"pad{mu}": (_model(800.0, mu), PAD_PUSH, 1e-4, ("mu_x", "density"), LIFT) for mu in (2.0, 0.5, 0.25, 0.15, 0.05)},
    "pad0.05_step1e-5": (_model(800.0, 0.05), PAD_PUSH, 1e-5, ("mu_x", "density"), LIFT),
    "pad0.05_4steps": (_model(800.0, 0.05), PAD_PUSH, 1e-4, ("mu_x", "density"), Release("lift", 4)),
    "pad0.15_backward_euler": (_model(800.0, 0.15), PAD_PUSH, 1e-4, ("mu_x", "density"),
                               Release("lift", 3, scheme="backward_euler")),
    **{f"compliant_pad{mu}": (_model(800.0, mu, COMPLIANT), PAD_PUSH, 1e-4,
                              ("mu_x", "density", "stiffness_xy", "stiffness_yaw"), LIFT) for mu in (2.0, 0.15, 0.05)},
    "bonded": (_model(1500.0), BONDED_PUSH, 3e-5, None, LIFT),
    "compliant_bonded": (_model(1500.0, grip=COMPLIANT), BONDED_PUSH, 1e-4,
                         ("mu_x", "angle", "density", "stiffness_xy", "stiffness_yaw"), LIFT),
}


def _margins(margins: list):
    """Wrap :func:`flipping_inputs` to record each step's smallest margin."""
    original = derivatives.flipping_inputs

    def recording(step, m, dm, kind, typical, skip=None):
        reach = np.abs(dm) * typical
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(reach > 0, np.abs(m)[:, :, None] / reach, np.inf)
        if skip is not None:
            ratio[skip] = np.inf
        i = np.unravel_index(int(np.argmin(ratio)), ratio.shape)
        margins.append((float(ratio[i]), KINDS[kind[i[0], i[1]]]))
        return original(step, m, dm, kind, typical, skip)

    derivatives.flipping_inputs = recording
    return original


def measure(name: str) -> dict:
    model, commands, rel_step, parameters, release = CASES[name]
    seen: list = []
    original = _margins(seen)
    plate_tol = gripper.PLATE_TOL
    gripper.PLATE_TOL = 1e-12 if name == "compliant_bonded" else plate_tol  # as the test: the hanging plate
    try:
        t0 = time.perf_counter()
        check = check_derivatives(model, commands, release=release, rel_step=rel_step, parameters=parameters)
        wall = time.perf_counter() - t0
    finally:
        derivatives.flipping_inputs, gripper.PLATE_TOL = original, plate_tol
    error = check.error.copy()
    if model.pad is None:  # the rest's vertical plate force: 0 by the put-down's root, its difference is noise
        error[check.outputs.index("force_z[rest]")] = 0.0
    i, j = np.unravel_index(int(np.argmax(error)), error.shape)
    smallest = min(seen)
    return {"case": name, "max_error": float(error.max()), "worst": f"{check.outputs[i]} / {check.inputs[j]}",
            "rel_step": rel_step, "release": f"{release.steps} {release.scheme}", "inputs": len(check.inputs), "smallest_transition_margin": smallest[0],
            "its_kind": smallest[1], "wall_s": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    args = parser.parse_args()
    rows = []
    for name in args.cases:
        rows.append(measure(name))
        r = rows[-1]
        print(f"{name:>18}: max error {r['max_error']:.2g} ({r['worst']}), smallest margin "
              f"{r['smallest_transition_margin']:.2g} ({r['its_kind']}), {r['wall_s']:.1f} s", flush=True)
    print(write_results("derivative_checks", {"bound": 1e-5, "transition_tol": 1e-6, "cases": rows}))


if __name__ == "__main__":
    main()
