"""Issue 39: a frictional pad unloaded by load control (the pad's height one more
unknown of each step's Newton loop, its load one more equation), its cost against
the pushes that loaded the block, and the Newton loop's stop (converged to the
tolerance or to rounding, stalled, capped)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

import fe_contact.stepping.newton as newton
from fe_contact import (Command, Friction, Gripper, Material, Model, PadLoad, Release, SolverOptions, block_mesh, release_to_rest,
                        run, step)
from fe_contact.stepping.release import MAX_STEPS
from pushplan.config.scenario import DEFAULT_PAD_LOAD_STEPS

WEIGHT_RTOL = 1e-6  # issue 39: N = W to 1e-6 at rest
FLOOR = Friction(0.65, 0.3, math.radians(20.0))
LOADS = [Command(dz=-2.5e-4)] + [Command(dx=8e-4)] * 3


def issue_block(pad_mu: float) -> Model:
    """Issue 39's case: rubber 28 x 22 x 14 mm, 6 x 5 x 3, floor 0.65 / 0.3 at 20 deg."""
    return Model(block_mesh((0.028, 0.022, 0.014), (6, 5, 3)), Material(2e6, 0.45, density=1000.0), FLOOR,
                 quadrature=2, pad=Friction(pad_mu, pad_mu))


@pytest.mark.parametrize("pad_mu, steps, scheme", [(0.0065, 4, "backward_euler"), (0.65, 4, "backward_euler"),
                                                   (0.0065, DEFAULT_PAD_LOAD_STEPS, "midpoint"),
                                                   (0.65, DEFAULT_PAD_LOAD_STEPS, "midpoint")])
def test_the_release_costs_no_more_newton_iterations_than_the_pushes(pad_mu, steps, scheme):
    """The slippery pad (0.0065: the old height search had not finished after 25
    minutes) and a pad of the floor's friction, pressed 0.25 mm and pushed 3 x
    0.8 mm, released in 4 backward-Euler load steps or in the default midpoint load
    steps (``DEFAULT_PAD_LOAD_STEPS``, their path to ``path_tol``): settled, N = W, at
    most the pushes' Newton iterations (issue 39's bound; measured 28 / 29 and 31 / 55
    midpoint at 6 steps; every pad 0.01 ... 100 x the floor's in
    benchmarks/results/release_cost_6.json, the worst 0.97)."""
    m = issue_block(pad_mu)
    state, pushes = run(m, LOADS)
    _, release, rest = release_to_rest(m, state, Release("lift", steps, scheme=scheme), pushes[-1])
    push_it, release_it = (sum(r.newton_iterations for r in reports) for reports in (pushes, release))
    print(f"pad {pad_mu}: release {release_it} / push {push_it} Newton iterations")
    assert rest.settled, rest.reason
    assert release[-1].normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)
    assert release_it <= push_it
    loads = [-r.upper_force[2] for r in release[:steps]]
    assert loads[-1] <= 1e-9 * m.weight and all(a > b for a, b in zip(loads[:-1], loads[1:], strict=True))  # the load falls to 0


def test_a_load_step_meets_its_load_and_finds_the_height():
    """One PadLoad step: the pad carries the load asked (to 1e-9 of it), its
    height is where that load is (higher for a smaller load), and the report's
    command is the pad's motion."""
    m = issue_block(0.65)
    state, pushes = run(m, LOADS[:2])
    loaded = -pushes[-1].upper_force[2]
    heights = []
    for fraction in (0.6, 0.3):
        after, report = step(m, state, PadLoad(fraction * loaded))
        assert report.converged, report.message
        assert -report.upper_force[2] == pytest.approx(fraction * loaded, rel=1e-9)
        assert report.command.dz == pytest.approx(after.upper_translation[2] - state.upper_translation[2], abs=1e-18)
        heights.append(after.upper_translation[2])
    assert state.upper_translation[2] < heights[0] < heights[1]


@pytest.mark.parametrize("make, match", [
    (lambda: Release("lift", 4, error_tol=1e-2), "error_tol was removed"),
    (lambda: Release("lift", 4, error_tol=1e-300), "error_tol was removed"),
    (lambda: Release("lift", MAX_STEPS + 1), "steps"),
    (lambda: Release("lift", 4, max_steps=10**9), "max_steps"),
    (lambda: PadLoad(-1.0), "load"),
    (lambda: PadLoad(math.inf), "load"),
    (lambda: PadLoad(1.0, (0.0,)), "retreat"),
])
def test_release_arguments_are_bounded(make, match):
    """Issue 43 (releases that never end): every argument of a release is checked
    at the public face; the release's work is bounded by its steps."""
    with pytest.raises(ValueError, match=match):
        make()


def test_a_pad_load_needs_a_pad():
    m = Model(block_mesh((0.02, 0.02, 0.01), (1, 1, 1)), Material(2e6, 0.3), FLOOR)
    with pytest.raises(ValueError, match="PadLoad"):
        step(m, run(m, [Command(dz=-1e-4)])[0], PadLoad(1.0))


# --- the Newton loop's stop (issue 39 item 7)

def small(**options) -> Model:
    return Model(block_mesh((0.02, 0.02, 0.01), (2, 2, 1)), Material(2e6, 0.3), Friction(0.3, 0.3),
                 options=SolverOptions(**options))


def test_a_newton_loop_that_stops_falling_says_stalled(monkeypatch):
    """A loop whose out-of-balance force stops falling (forced: every correction
    scaled by 0.99, a contraction of 1 %) ends early, 'stalled at r', instead of
    running out the cap."""
    original = newton._contact_correction

    def weak(*args, **kwargs):
        local, dU, failure = original(*args, **kwargs)
        return local, None if dU is None else 0.01 * dU, failure

    monkeypatch.setattr(newton, "_contact_correction", weak)
    _, reports = run(small(reuse_tangent=False), [Command(dz=-1e-4)])
    report = reports[-1]
    assert not report.converged and "stalled at r" in report.message, report.message
    assert report.newton_iterations < 100


def test_a_step_at_rounding_level_converges(monkeypatch):
    """A tolerance that rounding cannot meet (forced: a test that needs an
    out-of-balance force below 1e-30 of the scale): the loop stops where its
    last correction is at rounding level of the displacements, converged, and
    says so; with the rounding test removed it runs to 'stalled' or the cap."""
    original = newton._verdict

    def strict(opts, *args):
        return original(SimpleNamespace(**{**opts.__dict__, "newton_tol": 1e-30}), *args)

    monkeypatch.setattr(newton, "_verdict", strict)
    _, reports = run(small(), [Command(dz=-1e-4)])
    assert reports[-1].converged and "rounding" in reports[-1].message, reports[-1].message
    monkeypatch.setattr(newton, "ROUNDING_STEP", 0.0)
    _, reports = run(small(), [Command(dz=-1e-4)])
    assert not reports[-1].converged


def test_the_default_newton_cap_is_a_bound_not_a_test():
    """The default cap (100) is far above what a converging step takes on the
    cases of this file (at most 13 with a frictional pad)."""
    assert SolverOptions().newton_max_iter == 100
    m = issue_block(0.65)
    _, reports = run(m, LOADS[:2])
    assert max(r.newton_iterations for r in reports) < 30
    assert np.all([r.converged for r in reports])


@pytest.mark.parametrize("pad_mu, method", [(0.005, "newton"), (0.0, "newton"), (0.5, "uzawa")])
def test_releases_that_never_ended_end(pad_mu, method):
    """Issue 43's reproducers (each killed after 60 s before): on a 2 x 2 x 1 block a
    pad of 1/100 of the floor's friction, a frictionless pad, and a pad with the
    Uzawa local solver (the load equation's local solves are semismooth Newton's,
    tight, falling back to the chosen method) settle in 16 load steps, each
    within a few Newton iterations (measured at most 104 in all)."""
    m = Model(block_mesh((0.02, 0.02, 0.01), (2, 2, 1)), Material(2e6, 0.3, density=1000.0), Friction(0.5, 0.5),
              pad=Friction(pad_mu, pad_mu), options=SolverOptions(local_method=method))
    state, pushes = run(m, [Command(dz=-2e-4), Command(dx=3e-4)])
    _, release, rest = release_to_rest(m, state, Release("lift", 16), pushes[-1])
    assert rest.settled, rest.reason
    assert sum(r.newton_iterations for r in release) <= 16 * 10


# --- a compliant gripper with a frictional pad (issue 39 item 3): the plate's pose solved in the same loop

def pad_block(gripper=None) -> Model:
    """tests/test_pad.py's block, pad of the floor's friction."""
    floor = (0.6, 0.2, math.radians(20.0))
    return Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), Friction(*floor),
                 quadrature=2, pad=Friction(*floor), gripper=gripper or Gripper())


PAD_LOADS = [Command(dz=-4e-4)] + [Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))] * 2


def pushed_and_released(m):
    state, pushes = run(m, PAD_LOADS)
    assert all(r.converged for r in pushes), pushes[-1].message
    _, release, rest = release_to_rest(m, state, Release("lift", 4), pushes[-1])
    return pushes, release, rest


def test_a_stiff_compliant_gripper_with_a_pad_is_the_rigid_pad():
    """A gripper 1e9 x the block's shear stiffness: the loaded and the rest pose
    are the rigid pad's to 1e-9 of the lag (measured 5.5e-10)."""
    rigid = pushed_and_released(pad_block())
    k = 1e9 * pad_block().shear_stiffness
    stiff = pushed_and_released(pad_block(Gripper(k, k * (0.04**2 + 0.03**2) / 12)))
    lag = np.linalg.norm(rigid[0][-1].lag)
    assert stiff[2].settled, stiff[2].reason
    for a, b in ((rigid[0][-1], stiff[0][-1]), (rigid[1][-1], stiff[1][-1])):
        assert np.linalg.norm(a.lower_centroid - b.lower_centroid) <= 1e-9 * lag


def test_a_soft_compliant_gripper_with_a_pad_balances_its_springs_and_settles():
    """A gripper as stiff as the block in shear: the plate lags its command, the
    springs carry what the pad's contacts apply (in-plane resultant, to 1e-8 of
    it), and the release settles with N = W."""
    k = pad_block().shear_stiffness
    m = pad_block(Gripper(k, k * (0.04**2 + 0.03**2) / 12))
    pushes, release, rest = pushed_and_released(m)
    last = pushes[-1]
    pad_force = last.upper_force[:2]
    np.testing.assert_allclose(last.gripper_force[:2], pad_force, rtol=0, atol=1e-8 * np.linalg.norm(pad_force))
    assert np.linalg.norm(last.plate[:2] - [1.2e-3, 4e-4]) > 1e-4  # the plate lags
    assert rest.settled, rest.reason
    assert release[-1].normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)


def test_a_bracket_whose_probes_no_local_solve_solves_gives_up_after_a_few():
    """The load equation's bracket (pad_load.LoadDrive._bracket) shortens a probe
    that no local method solves and gives up after MAX_FAILED_PROBES of them,
    well before the evaluation cap, also where every other probe converges (a pad
    10 x the floor's crept so towards a height beyond which no local solve
    converged: each failure costs every method, the paper's Uzawa up to 20000
    iterations; 211 of its 221 s release)."""
    from fe_contact.stepping.pad_load import MAX_FAILED_PROBES, MAX_LOAD_EVALUATIONS, LoadDrive

    def drive(solvable):
        calls = []
        stub = SimpleNamespace(evaluations=0, cap=MAX_LOAD_EVALUATIONS, slope=1.0, tolerance=1e-12)

        def at(dh):
            calls.append(dh)
            stub.evaluations += 1
            return SimpleNamespace(converged=solvable(len(calls))), 1.0 - dh * 1e-3  # g > 0: no sign change near
        return LoadDrive._bracket(stub, at, SimpleNamespace(converged=True), 1.0), calls

    found, calls = drive(lambda n: False)
    assert found is None and len(calls) == MAX_FAILED_PROBES < MAX_LOAD_EVALUATIONS
    assert calls[1] == pytest.approx(calls[0] / 4)  # each failed probe a quarter of the last step
    found, calls = drive(lambda n: n % 2 == 0)  # every other probe converges: the creep
    assert found is None and len(calls) == 2 * MAX_FAILED_PROBES - 1


def test_regula_falsi_steps_around_a_point_no_local_solve_solves():
    """Inside the load equation's bracket (pad_load.LoadDrive._illinois) a point
    that no local method solves is replaced by the point half way to an end, up to
    MAX_FAILED_PROBES of them: g(h) = 0.6 - 2 h on [0, 1], unsolvable on (0.4, 0.6)
    around the first bisection point, is solved (it gave up there); unsolvable
    everywhere inside, the regula falsi stops after MAX_FAILED_PROBES points."""
    from fe_contact.stepping.pad_load import MAX_FAILED_PROBES, MAX_LOAD_EVALUATIONS, LoadDrive

    def illinois(solvable):
        calls = []
        stub = SimpleNamespace(evaluations=0, cap=MAX_LOAD_EVALUATIONS, height=1.0, tolerance=1e-9,
                               _secant=lambda *args: None)

        def at(h):
            calls.append(h)
            stub.evaluations += 1
            return SimpleNamespace(converged=solvable(h)), 0.6 - 2.0 * h
        ends = (0.0, 0.6, SimpleNamespace(converged=True)), (1.0, -1.4, SimpleNamespace(converged=True))
        return LoadDrive._illinois(stub, at, *ends), calls

    (local, g, h), calls = illinois(lambda h: not 0.4 < h < 0.6)
    assert local.converged and abs(g) <= 1e-9 and h == pytest.approx(0.3) and 0.4 < calls[0] < 0.6
    _, calls = illinois(lambda h: False)
    assert len(calls) == MAX_FAILED_PROBES


def test_a_sticky_pad_released_in_six_load_steps_settles():
    """A pad 100 x the floor's on the small block of benchmarks/release_steps.py,
    released in 6 load steps: its last step brackets the pad's opening and a
    local solve inside the bracket fails (it ended unsettled, the pad carrying
    0.24 N, before regula falsi stepped around such points)."""
    floor = Friction(0.6, 0.2, math.radians(20.0))
    m = Model(block_mesh((0.04, 0.03, 0.02), (3, 2, 2)), Material(2e6, 0.45, density=1000.0), floor, quadrature=2,
              pad=Friction(60.0, 20.0, math.radians(20.0)))
    push = Command(dx=6e-4, dy=2e-4, dtheta=math.radians(1.0))
    state, pushes = run(m, [Command(dz=-4e-4), push, push])
    _, release, rest = release_to_rest(m, state, Release("lift", 6), pushes[-1])
    assert rest.settled, rest.reason
    assert release[-1].normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)


def test_a_sticky_pads_release_costs_few_local_newton_steps_and_no_uzawa(monkeypatch):
    """A pad 100 x the floor's (65 / 30) released in 4 load steps (the issue's block on
    4 x 3 x 2): each of its Newton iterations costs a few local solves.  Its load
    equation's probes once failed through every method (warm Newton 100 steps three
    times, from zero, the paper's Uzawa 20000 sweeps, 2-3 s each) and each iteration
    of a step that ended past a jump of the load bracketed the jump again: 7436 local
    Newton steps and 6 Uzawa solves for 49 Newton iterations, 14 s against the
    pushes' 0.3 s; now about 2000 steps, none by Uzawa (benchmarks/release_cost.py)."""
    solves = []

    def counted(*args, **kwargs):
        local = solve_checked(*args, **kwargs)
        solves.append((args[5], local.iterations))
        return local
    from fe_contact.contact.local_solver import solve_checked
    ratio = 100.0
    m = Model(block_mesh((0.028, 0.022, 0.014), (4, 3, 2)), Material(2e6, 0.45, density=1000.0), FLOOR, quadrature=2,
              pad=Friction(FLOOR.mu_x * ratio, FLOOR.mu_y * ratio, FLOOR.angle))
    state, pushes = run(m, LOADS)
    monkeypatch.setattr(newton, "solve_checked", counted)
    _, release, rest = release_to_rest(m, state, Release("lift", 4), pushes[-1])
    iterations = sum(r.newton_iterations for r in release)
    steps = sum(n for method, n in solves if method == "newton")
    print(f"{len(solves)} local solves, {steps} Newton steps, {iterations} release Newton iterations")
    assert rest.settled, rest.reason
    assert release[-1].normal_force == pytest.approx(m.weight, rel=WEIGHT_RTOL)
    assert all(method == "newton" for method, _ in solves)  # no every-method fallback at a probe
    assert steps <= 60 * iterations  # measured 41 (152 before)


def test_a_step_past_a_jump_checks_it_with_one_local_solve_per_iteration():
    """A load step that ended past a jump of the pad's load (the pad let go at once)
    checks at its next Newton iteration that the jump is still just below the current
    height with one local solve (pad_load.LoadDrive._still_past_jump), warm from the
    jump's pressing side: g(h) = 0.01 below h = -1e-13 (relative to h_i), -P above;
    a jump that moved above h_i (g > 0 there too) is no short cut."""
    from fe_contact.stepping.pad_load import JUMP_WIDTH, LoadDrive

    def still(jump_at):
        calls = []
        stub = SimpleNamespace(height=1e-3, tolerance=1e-12)

        def at(dh, warm=None):
            calls.append((dh, warm))
            return SimpleNamespace(converged=True, r=np.full((1, 3), dh)), 0.01 if dh < jump_at else -0.05
        return LoadDrive._still_past_jump(stub, at, "open", -0.05, "pressing"), calls, stub

    found, calls, stub = still(-1e-16)
    assert found == ("open", -0.05, 0.0) and len(calls) == 1 and calls[0][1] == "pressing"
    assert calls[0][0] == pytest.approx(-JUMP_WIDTH * 1e-3) and stub.jump == pytest.approx(0.06)
    found, calls, _ = still(-1.0)  # the pad open at h_i - JUMP_WIDTH |h_i| too: the full bracket follows
    assert found is None and len(calls) == 1
