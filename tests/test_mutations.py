"""Tests that kill plausible physics bugs the rest of the suite let through (issue 27;
which test guards which equation: tests/test_mutations.md).

- the paper's per-node ``rho = 1 / min(w_nn, w_txtx, w_tyty)`` (sect. 8, eq. 44),
- the planner's effort weight, on the mean squared step (``effort_weight * effort / K``),
- the sense of the orthotropy angle, seen in world coordinates by an FE push at 30 deg.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fe_contact import Command, build_model, initial_state, run
from fe_contact.contact.uzawa import paper_rho
from pushplan.config import parse_scenario
from pushplan.config.plan import parse_plan
from pushplan.planning.nlp import ReducedPlanner
from pushplan.planning.reduced_model import PushParameters, simulate_reduced

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
OBJECTIVE_RTOL = 1e-6  # NLP objective vs its value recomputed from the commands (ipopt tol 1e-10)
FULL_STEP_RTOL = 1e-6  # |u_k| / max_step of an out-of-reach plan
STEEL = PushParameters(mu_x=0.3, mu_y=0.05, angle=0.0, normal_force=9.0e5, compliance=3.5e-10)
RIGID = PushParameters(mu_x=0.3, mu_y=0.05, angle=0.4, normal_force=9.0e5, compliance=1e-18)


# -- the paper's rho (sect. 8, eq. 44) ------------------------------------------------------
def test_paper_rho_is_the_inverse_of_the_smallest_diagonal_flexibility():
    """Three contacts with known diagonal blocks: (2, 4, 8) -> 1/2; a contact without
    normal flexibility (0, 3, 5) -> 1/3 (positive entries only); none at all -> 1."""
    W = np.diag([2.0, 4.0, 8.0, 0.0, 3.0, 5.0, 0.0, 0.0, 0.0])
    W[0, 1] = W[1, 0] = 0.5  # off-diagonal terms do not enter
    np.testing.assert_array_equal(paper_rho(W), [0.5, 1.0 / 3.0, 1.0])


# -- the planner's effort weight --------------------------------------------------------------
def _spec(**plan_table):
    data = tomllib.loads((SCENARIOS / "plan_steel_case3.toml").read_text())
    data["block"].update(elements=[4, 4, 2], quadrature=2)
    data["plan"] = {"steps": 4, "max_step": 4e-4, "tolerance": 1e-6, **plan_table}
    return parse_plan(parse_scenario(data))


def test_nlp_objective_is_the_miss_plus_the_weighted_mean_squared_step():
    """``J = |p_K - x*|^2 / tol^2 + w sum_k |u_k / max_step|^2 / K``, recomputed from the
    commands through the reduced model's return mapping."""
    spec = _spec(x=9e-4, y=9e-4, effort_weight=2.0, tolerance=2e-4)
    sol = ReducedPlanner(STEEL, spec).solve()
    assert sol.success
    final = simulate_reduced(STEEL, sol.commands).lower[-1, :2]
    miss = float(np.sum((final - spec.target[:2]) ** 2)) / spec.tolerance**2
    effort = float(np.sum((sol.commands[:, :2] / spec.max_step) ** 2)) / spec.steps
    assert effort > 0.1 and miss > 1e-3  # both terms matter at this weight and tolerance
    assert sol.objective == pytest.approx(miss + spec.effort_weight * effort, rel=OBJECTIVE_RTOL)


def test_an_out_of_reach_target_gets_full_steps_towards_it():
    """Target at twice the reach ``K max_step``, tolerance = reach, rigid block: with
    ``s = |u_k| / max_step`` equal in every step, ``J(s) = (2 - s)^2 + w s^2``, decreasing
    on [0, 1] for ``w < 1``: every command is a full step at the target and
    ``J = 1 + w``.  (A weight on the sum instead of the mean, ``w K^2``, would stop at
    ``s = 2 / (1 + w K^2)``.)"""
    K, m, w = 4, 4e-4, 0.5
    direction = np.array([math.cos(0.3), math.sin(0.3)])
    spec = _spec(x=2 * K * m * direction[0], y=2 * K * m * direction[1], steps=K, max_step=m,
                 tolerance=K * m, effort_weight=w)
    assert not spec.reachable
    sol = ReducedPlanner(RIGID, spec).solve()
    assert sol.success
    np.testing.assert_allclose(np.hypot(*sol.commands[:, :2].T), m, rtol=FULL_STEP_RTOL)
    np.testing.assert_allclose(sol.commands[:, :2] / m, np.tile(direction, (K, 1)), atol=1e-6)
    assert sol.objective == pytest.approx(1.0 + w, rel=OBJECTIVE_RTOL)


# -- the sense of the orthotropy angle, in world coordinates --------------------------------
def test_fe_lower_face_deviates_towards_the_low_friction_axis_at_30_deg():
    """Paper case 3 friction (mu_x = 0.3 along t_x, mu_y = 0.05 along t_y) with the axes
    turned by +30 deg (counter-clockwise from world x, seen from +z): t_x points at
    30 deg, t_y at 120 deg.  A push at 75 deg, half-way between them, drags the lower
    face behind the upper one by a lag along ``M^2 s`` (eq. 23-30), turned towards the
    stiff axis t_x; the lower face's path therefore turns towards t_y: its direction lies
    between 75 and 120 deg.  Axes turned the wrong way (t_x at -30 deg, t_y at 60 deg)
    turn it below 75 deg; 0 and 90 deg look the same both ways."""
    model = build_model((0.02, 0.02, 0.01), (4, 4, 2), 210e9, 0.3, 0.3, 0.05, angle=math.radians(30.0),
                        quadrature=2)
    push = math.radians(75.0)
    cmds = [Command(dz=-1e-4)] + [Command(dx=3.2e-4 * math.cos(push), dy=3.2e-4 * math.sin(push))] * 4
    _, reports = run(model, cmds, initial_state(model))
    assert all(r.converged for r in reports)
    moved = reports[-1].lower_centroid[:2] - reports[0].lower_centroid[:2]
    heading = math.degrees(math.atan2(moved[1], moved[0]))
    assert 75.0 + 0.2 < heading < 120.0, heading
    # the lag (upper minus lower) leans from the push towards t_x = (cos 30, sin 30)
    lag = reports[-1].lag
    t_y = np.array([-math.sin(math.radians(30.0)), math.cos(math.radians(30.0))])
    push_dir = np.array([math.cos(push), math.sin(push)])
    assert lag @ push_dir > 0 and lag @ t_y < (lag @ push_dir) * (push_dir @ t_y)
