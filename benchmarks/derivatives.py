"""Cost of exact derivatives (issue 30), both measurements in one run:

1. A rollout with its exact derivatives against a plain rollout (press + 4
   pushes, rubber block of ``plan_rubber``) on two meshes: the totals (J = 4 K
   input columns of the commands, and with 5 parameters), the parameter-free
   part (the plain rollout plus the linearisation of each converged step:
   tangent, flexibility matrix, LU of the condensed law) and the cost of one
   input column in a step, in back-substitutions with the step's factor; and
   the reverse-mode gradient of one scalar (all inputs) against the plain rollout.
2. Identification of (mu_x, mu_y, angle) on a foam block from noisy
   observations, with the exact Jacobian and with forward differences: FE
   rollouts, wall time, estimates.

    python benchmarks/derivatives.py

Writes ``benchmarks/results/derivatives.json``.
"""

from __future__ import annotations

import time
import tomllib

import numpy as np

from _common import write_results
from fe_contact import (Command, Friction, Material, Model, block_mesh, initial_state, rollout_derivatives,
                        rollout_gradient, run, step)
from fe_contact.stepping.sensitivity import HeldLinearisation
from pushplan.config.observations import Observations
from pushplan.config.scenario import parse_scenario
from pushplan.identify.fit import identify, scales
from pushplan.identify.noise import NoiseModel
from pushplan.run import drive
from pushplan.run.observations import observations_from_steps

MESHES = [(8, 8, 2), (12, 12, 4)]
COMMANDS = [Command(dz=-3e-4)] + [Command(dx=8e-4, dy=4e-4, dtheta=0.01)] * 4
PARAMETERS = ("mu_x", "mu_y", "angle", "young", "poisson")
REPEATS = 3
FOAM = """
name = "foam"
[block]
size = [0.02, 0.02, 0.01]
elements = [4, 4, 2]
quadrature = 2
[material]
young = 1e6
poisson = 0.3
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = {angle_deg}
[[load]]
dz = -5e-4
[[load]]
distance = 1e-3
direction_deg = 0
repeat = 3
[[load]]
distance = 1e-3
direction_deg = 90
repeat = 3
[solver]
local_method = "newton"
"""


def best(f, repeats=REPEATS) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def rollout_cost(elements) -> dict:
    """Plain rollout, derivative rollouts, and their parts: the linearisation of
    each converged step (tangent at the converged configuration, flexibility
    matrix, the condensed law's LU) and the solve per input column."""
    model = Model(block_mesh((0.02, 0.02, 0.01), elements), Material(5e6, 0.45), Friction(0.8, 0.3, 0.3))
    K = len(COMMANDS)
    plain = best(lambda: run(model, COMMANDS))
    commands_only = best(lambda: rollout_derivatives(model, COMMANDS, parameters=()))
    with_params = best(lambda: rollout_derivatives(model, COMMANDS, parameters=PARAMETERS))
    weights = np.ones((K, 9))
    adjoint = best(lambda: rollout_gradient(model, COMMANDS, weights, parameters=PARAMETERS))
    states = [initial_state(model)]
    for c in COMMANDS:
        states.append(step(model, states[-1], c)[0])
    linearise, per_column, back_substitution = 0.0, 0.0, 0.0
    rng = np.random.default_rng(0)
    for start, (end, report) in zip(states[:-1], [step(model, s, c) for s, c in zip(states[:-1], COMMANDS, strict=True)], strict=True):
        make = lambda: HeldLinearisation(model, start.displacement, end.displacement,  # noqa: E731
                                         report.reaction_local, report.node_status)
        linearise += best(make)
        lin = make()
        J = 4 * K + len(PARAMETERS)
        d = [rng.normal(size=(model.mesh.n_dofs, J)), rng.normal(size=(model.upper_dofs.size, J)),
             np.vstack([rng.normal(size=(3, J)), np.zeros((3, J))])]  # no material columns: their forces are apart
        one = [a[:, :1] for a in d]
        per_column += (best(lambda: lin.solve(*d), 10) - best(lambda: lin.solve(*one), 10)) / (J - 1)
        rhs = rng.normal(size=model.free_dofs.size)
        back_substitution += best(lambda: lin.tangent.solve(rhs), 20) / K
    return {"elements": list(elements), "free_dofs": int(model.free_dofs.size), "steps": K,
            "plain_rollout_s": plain, "derivative_rollout_commands_only_s": commands_only,
            "derivative_rollout_commands_and_5_parameters_s": with_params,
            "inputs_with_parameters": 4 * K + len(PARAMETERS),
            "linearisations_s": linearise, "parameter_free_ratio": (plain + linearise) / plain,
            "per_input_per_step_s": per_column / K, "back_substitution_s": back_substitution,
            "per_input_in_back_substitutions": per_column / K / back_substitution,
            "total_ratio_commands_only": commands_only / plain,
            "total_ratio_with_parameters": with_params / plain,
            "adjoint_gradient_with_parameters_s": adjoint, "adjoint_ratio": adjoint / plain}


def foam(**friction):
    return parse_scenario(tomllib.loads(FOAM.format(**friction)))


def identification() -> dict:
    truth = foam(mu_x=0.6, mu_y=0.35, angle_deg=25.0)
    clean = observations_from_steps(drive(truth.model(), truth.commands).summary.steps)
    rng = np.random.default_rng(3)
    values = {k: v + (rng.normal(0, 1e-6, v.shape) if k in ("lower_x", "lower_y") else rng.normal(0, 0.01 * abs(v)))
              for k, v in clean.values.items() if k != "lower_yaw_deg"}
    obs, noise = Observations(clean.commands, values), NoiseModel(1e-6, 1e-3, 0.01)
    guess = foam(mu_x=0.5, mu_y=0.5, angle_deg=0.0)
    out = {}
    for label, exact in (("exact", True), ("forward_differences", False)):
        t0 = time.perf_counter()
        r = identify(guess, obs, noise, exact=exact, model_error=False)  # the fit alone
        out[label] = {"estimate": dict(zip(r.names, r.estimate, strict=True)), "sigma": dict(zip(r.names, r.sigma, strict=True)),
                      "fe_rollouts": r.fe_rollouts, "iterations": r.iterations, "converged": r.converged,
                      "wall_s": time.perf_counter() - t0}
    e, f = out["exact"], out["forward_differences"]
    names = tuple(e["estimate"])
    est_e, est_f = np.array(list(e["estimate"].values())), np.array(list(f["estimate"].values()))
    out["max_estimate_gap_scaled"] = float(np.max(np.abs(est_e - est_f) / scales(names, est_e)))
    out["rollout_ratio"] = f["fe_rollouts"] / e["fe_rollouts"]
    out["wall_ratio"] = f["wall_s"] / e["wall_s"]
    return out


def main() -> None:
    costs = [rollout_cost(e) for e in MESHES]
    for c in costs:
        print(f"{c['elements']}: plain {c['plain_rollout_s']:.3f} s, with derivatives "
              f"{c['derivative_rollout_commands_and_5_parameters_s']:.3f} s ({c['inputs_with_parameters']} inputs); "
              f"parameter-free {c['parameter_free_ratio']:.2f}x plain, per input and step "
              f"{c['per_input_in_back_substitutions']:.2f} back-substitutions; adjoint gradient "
              f"{c['adjoint_ratio']:.2f}x plain")
    ident = identification()
    print(f"identification: exact {ident['exact']['fe_rollouts']} rollouts {ident['exact']['wall_s']:.2f} s, "
          f"forward differences {ident['forward_differences']['fe_rollouts']} rollouts "
          f"{ident['forward_differences']['wall_s']:.2f} s; estimates agree to {ident['max_estimate_gap_scaled']:.1e}")
    print(write_results("derivatives", {"rollout_cost": costs, "identification": ident}))


if __name__ == "__main__":
    main()
