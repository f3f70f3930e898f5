"""Is (block pose, gripper lag) a Markov state of the FE push? (issue 40 item 4: the
decision on a Crocoddyl action model), in one run:

On ``plan_rubber``'s block at the planning mesh (6 x 6 x 2, quadrature 2), two command
histories, A (x, x, then y) and B (found by Gauss-Newton with the exact Jacobian from y,
x, x), end in the same reduced state: the same lower-face pose (x, y, yaw) and the same
gripper (plate) pose, so the same lag, to 1e-12 m / rad.  The same next command from
both FE states then gives different next poses: a transition on the reduced state, what
an ``ActionModelAbstract.calc(data, x, u)`` computes from ``x`` alone, must be wrong by at
least half that difference for one of them.  Compared with the plan's tolerance (5 um,
0.1 deg).

    python benchmarks/markov_state.py

Writes ``benchmarks/results/markov_state.json``.
"""

from __future__ import annotations

import numpy as np

from _common import write_results
from pushplan.config.plan import parse_plan, press_commands
from pushplan.config.scenario import load_scenario
from pushplan.planning.push_model import PushModel
from pushplan.resources import scenario_path

A = np.array([[8e-4, 0.0, 0.0], [8e-4, 0.0, 0.0], [0.0, 6e-4, 0.0]])
B0 = np.array([[0.0, 6e-4, 0.0], [8e-4, 0.0, 0.0], [8e-4, 0.0, 0.0]])
NEXT = {"on along x": [[5e-4, 0.0, 0.0]], "on along y": [[0.0, 5e-4, 0.0]], "back along -x": [[-5e-4, 0.0, 0.0]],
        "turn 0.05 rad": [[0.0, 0.0, 0.05]], "6 pushes (0.5, 0.25) mm": [[5e-4, 2.5e-4, 0.0]] * 6,
        "6 pushes (-0.3, 0.4) mm": [[-3e-4, 4e-4, 0.0]] * 6}
MAX_NEWTON = 30
TRUST = 3e-4
SCALE = np.array([1.0, 1.0, 0.01, 1.0, 1.0, 0.01])
"""m, m, m/rad: yaw residuals weighed by a lever of 10 mm (half the block)."""


def match(push: PushModel, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, int]:
    """Commands near ``b`` whose final lower-face pose and summed command equal ``a``'s
    (Levenberg-Marquardt with the exact Jacobian, each step within ``TRUST`` m)."""
    goal = np.concatenate([push.rollout(a)[-1], a.sum(axis=0)])
    mu = 1e-12
    for it in range(MAX_NEWTON):
        jac = push.rollout_with_jacobian(b)
        r = (np.concatenate([jac.poses[-1], b.sum(axis=0)]) - goal) * SCALE
        if np.abs(r).max() <= 1e-12:
            return b, float(np.abs(r).max()), it
        J = np.vstack([jac.d_commands[-1].reshape(3, -1), np.tile(np.eye(3), len(b))]) * SCALE[:, None]
        while True:
            step = -np.linalg.solve(J.T @ J + mu * np.eye(J.shape[1]), J.T @ r).reshape(b.shape)
            if np.abs(step[:, :2]).max() <= TRUST and np.abs(step[:, 2]).max() <= 0.05:
                break
            mu *= 10
        b = b + step
        mu = max(mu / 10, 1e-14)
    raise RuntimeError(f"no match in {MAX_NEWTON} steps: residual {np.abs(r).max():.3g}")


def end_state(push: PushModel, commands):
    state, pose = push.pressed.state, None
    for c in commands:
        state, pose = push.step(state, c)
    return state, pose


def main() -> None:
    scenario = load_scenario(scenario_path("plan_rubber.toml"))
    spec = parse_plan(scenario)
    push = PushModel(scenario.model((6, 6, 2), 2), press_commands(scenario))
    b, residual, newton = match(push, A, B0.copy())
    (sa, pa), (sb, pb) = end_state(push, A), end_state(push, b)
    out = {"A": A, "B": b, "gauss_newton_steps": newton, "match_residual": residual,
           "pose_difference": pb - pa, "plate_difference": sb.plate - sa.plate,
           "tolerance_m": spec.tolerance, "yaw_tolerance_rad": spec.yaw_tolerance, "next": {}}
    fa, fb = push.rollout_with_forces(A[-1:], start=end_state(push, A[:-1])[0])[1][-1], \
        push.rollout_with_forces(b[-1:], start=end_state(push, b[:-1])[0])[1][-1]
    out["force_difference_N"], out["force_A_N"] = fb - fa, fa
    print(f"matched in {newton} Gauss-Newton steps; reduced states differ by {np.abs(pb - pa).max():.2e} (pose), "
          f"{np.abs(sb.plate - sa.plate).max():.2e} (plate); gripper forces {fa} vs {fb} N")
    for name, c in NEXT.items():
        na, nb = push.rollout(c, start=sa)[-1], push.rollout(c, start=sb)[-1]
        d = nb - na
        out["next"][name] = {"difference": d, "position_m": float(np.hypot(d[0], d[1])), "yaw_rad": float(abs(d[2]))}
        print(f"next {name:24s}: position differs by {np.hypot(d[0], d[1]) * 1e6:7.2f} um "
              f"({np.hypot(d[0], d[1]) / spec.tolerance:5.2f} x tolerance), yaw by {abs(d[2]):.2e} rad")
    print("wrote", write_results("markov_state", _lists(out)))


def _lists(o):
    """``o`` with its arrays as lists (JSON)."""
    if isinstance(o, dict):
        return {k: _lists(v) for k, v in o.items()}
    return o.tolist() if isinstance(o, np.ndarray) else o


if __name__ == "__main__":
    main()
