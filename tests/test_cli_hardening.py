"""CLI hardening (issue 9): bad input is rejected before any work with a one-line
message naming the key and value (exit 2, no traceback, no output); solver failure
is an outcome (exit 3, valid summary.json with the finished steps and the reason);
reruns are identical; long pushes stay in equilibrium with non-negative dissipation
and reach the steady sliding of the elliptic friction law."""

import importlib
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from pushplan.cli import EXIT_BAD_INPUT, EXIT_SOLVER_FAILURE, main
from tiny_inputs import BASE, SWEEP  # the tiny scenario and sweep shared by the CLI tests

EQUILIBRIUM_TOL = 1e-8  # issue: equilibrium to 1e-8 in every step
STEADY_RTOL = 1e-4  # steady sliding: lower-face increment = push increment, dissipation = N |M du|
WALL_TIME_KEYS = {"elapsed_s", "wall_time_s"}


def edit(text, old, new):
    assert text.count(old) == 1, f"test table: {old!r} must occur once"
    return text.replace(old, new)


def scenario_case(old, new, *fragments):
    return ("scenario", (old, new), fragments)


# (kind, edit, fragments the one-line message must contain)
BAD_INPUTS = {
    "size negative": scenario_case("size = [0.02, 0.02, 0.01]", "size = [-0.02, 0.02, 0.01]", "block.size[0]", "-0.02"),
    "size zero": scenario_case("size = [0.02, 0.02, 0.01]", "size = [0.02, 0.0, 0.01]", "block.size[1]", "0.0"),
    "size nan": scenario_case("size = [0.02, 0.02, 0.01]", "size = [0.02, 0.02, nan]", "block.size[2]", "nan"),
    "size inf": scenario_case("size = [0.02, 0.02, 0.01]", "size = [inf, 0.02, 0.01]", "block.size[0]", "inf"),
    "size two values": scenario_case("size = [0.02, 0.02, 0.01]", "size = [0.02, 0.02]", "block.size", "[0.02, 0.02]"),
    "size string": scenario_case("size = [0.02, 0.02, 0.01]", 'size = "big"', "block.size", "'big'"),
    "elements zero": scenario_case("elements = [2, 2, 1]", "elements = [0, 2, 1]", "block.elements[0]", "0"),
    "elements negative": scenario_case("elements = [2, 2, 1]", "elements = [2, -3, 1]", "block.elements[1]", "-3"),
    "elements float": scenario_case("elements = [2, 2, 1]", "elements = [2, 2, 1.5]", "block.elements[2]", "1.5"),
    "elements too many": scenario_case("elements = [2, 2, 1]", "elements = [1000, 1000, 10]", "block.elements", "1000"),
    "quadrature 4": scenario_case("quadrature = 2", "quadrature = 4", "block.quadrature", "4"),
    "quadrature 0": scenario_case("quadrature = 2", "quadrature = 0", "block.quadrature", "0"),
    "young zero": scenario_case("young = 210e9", "young = 0.0", "material.young", "0.0"),
    "young negative": scenario_case("young = 210e9", "young = -5.0", "material.young", "-5.0"),
    "young string": scenario_case("young = 210e9", 'young = "steel"', "material.young", "'steel'"),
    "poisson 0.5": scenario_case("poisson = 0.3", "poisson = 0.5", "material.poisson", "0.5"),
    "poisson -1": scenario_case("poisson = 0.3", "poisson = -1.0", "material.poisson", "-1.0"),
    "poisson nan": scenario_case("poisson = 0.3", "poisson = nan", "material.poisson", "nan"),
    "mu_x negative": scenario_case("mu_x = 0.3", "mu_x = -0.1", "friction.mu_x", "-0.1"),
    "mu_y nan": scenario_case("mu_y = 0.1", "mu_y = nan", "friction.mu_y", "nan"),
    "mu_y inf": scenario_case("mu_y = 0.1", "mu_y = inf", "friction.mu_y", "inf"),
    "mu_x bool": scenario_case("mu_x = 0.3", "mu_x = true", "friction.mu_x", "True"),
    "unknown block key": scenario_case("quadrature = 2", "quadrature = 2\ncolour = 1", "block.colour"),
    "unknown top key": scenario_case('name = "tiny"', 'name = "tiny"\ngravity = 9.81', "gravity"),
    "unknown load key": scenario_case("direction_deg = 45.0", "direction_deg = 45.0\nspeed = 1.0", "load[1].speed"),
    "unknown table": scenario_case("[block]", "[blocks]", "blocks"),
    "missing material": scenario_case("[material]\nyoung = 210e9\npoisson = 0.3\n", "", "[material]"),
    "missing young": scenario_case("young = 210e9\n", "", "material.young"),
    "name not string": scenario_case('name = "tiny"', "name = 5", "name", "5"),
    "description not string": scenario_case('name = "tiny"', 'name = "h"\ndescription = 7', "description", "7"),
    "load not array": scenario_case("[[load]]\ndz = -1e-4\n[[load]]\ndistance = 0.32e-3\ndirection_deg = 45.0",
                                    "[load]\ndz = -1e-4", "load", "{'dz': -0.0001}"),
    "dx with distance": scenario_case("distance = 0.32e-3", "distance = 0.32e-3\ndx = 1e-4", "load[1]", "dx"),
    "distance without angle": scenario_case("direction_deg = 45.0\n", "", "load[1]", "direction_deg"),
    "distance negative": scenario_case("distance = 0.32e-3", "distance = -1.0", "load[1].distance", "-1.0"),
    "dz nan": scenario_case("dz = -1e-4", "dz = nan", "load[0].dz", "nan"),
    "direction inf": scenario_case("direction_deg = 45.0", "direction_deg = -inf", "load[1].direction_deg", "-inf"),
    "repeat zero": scenario_case("direction_deg = 45.0", "direction_deg = 45.0\nrepeat = 0", "load[1].repeat", "0"),
    "repeat float": scenario_case("direction_deg = 45.0", "direction_deg = 45.0\nrepeat = 2.5", "load[1].repeat", "2.5"),
    "repeat huge": scenario_case("direction_deg = 45.0", "direction_deg = 45.0\nrepeat = 100000000",
                                 "load[1].repeat", "100000000"),
    "no load steps": scenario_case("[[load]]\ndz = -1e-4\n[[load]]\ndistance = 0.32e-3\ndirection_deg = 45.0", "",
                                   "nothing to simulate", "base.toml"),
    "local_method unknown": scenario_case('local_method = "newton"', 'local_method = "magic"',
                                          "solver.local_method", "'magic'"),
    "newton_tol zero": scenario_case('local_method = "newton"', "newton_tol = 0.0", "solver.newton_tol", "0.0"),
    "newton_max_iter zero": scenario_case('local_method = "newton"', "newton_max_iter = 0", "solver.newton_max_iter", "0"),
    "acceleration negative": scenario_case('local_method = "newton"', "acceleration = -1", "solver.acceleration", "-1"),
    "reuse_tangent string": scenario_case('local_method = "newton"', 'reuse_tangent = "yes"',
                                          "solver.reuse_tangent", "'yes'"),
    "malformed toml": scenario_case("size = [0.02, 0.02, 0.01]", "size = [0.02, 0.02,", "malformed TOML", "base.toml"),
    "missing scenario file": ("argv", ["simulate", "{tmp}/missing.toml", "--out", "{out}"], ("not found", "missing.toml")),
    "scenario is a folder": ("argv", ["simulate", "{tmp}", "--out", "{out}"], ("cannot read scenario file",)),
    "scenario not utf-8": ("bytes", b"name = \"\xff\xfe\"\n", ("malformed TOML", "base.toml")),
    "out under a file": ("argv", ["simulate", "{base}", "--out", "{base}/sub"], ("cannot create output folder", "sub")),
    "out is a file": ("argv", ["simulate", "{base}", "--out", "{base}"], ("not a folder", "base.toml")),
    "commands missing": ("argv", ["simulate", "{base}", "--out", "{out}", "--commands", "{tmp}/plan.json"],
                         ("commands file not found", "plan.json")),
    "commands malformed": ("commands", "{\"commands\": [", ("cannot read commands file", "plan.json")),
    "commands bad value": ("commands", '{"commands": [{"dx": "far"}]}', ("commands[0].dx", "'far'")),
    "commands empty": ("commands", '{"commands": []}', ("nothing to simulate", "plan.json")),
    "sweep negative mu": ("sweep", ('"friction.mu_y" = [0.1, 0.2]', '"friction.mu_y" = [0.1, -0.2]'),
                          ("friction.mu_y", "-0.2")),
    "sweep unknown key": ("sweep", ('"friction.mu_y"', '"friction.mu_z"'), ("friction.mu_z",)),
    "sweep empty grid list": ("sweep", ("[0.1, 0.2]", "[]"), ("grid.friction.mu_y", "[]")),
    "sweep repeated values": ("sweep", ("[0.1, 0.2]", "[0.1, 0.1]"), ("grid.friction.mu_y", "[0.1, 0.1]")),
    "sweep bad path": ("sweep", ('"friction.mu_y"', '"mu_y"'), ("'mu_y'",)),
    "sweep load key absent": ("sweep", ('"friction.mu_y" = [0.1, 0.2]', '"load.speed" = [1.0]'), ("load.speed",)),
    "sweep missing base": ("sweep", ('base = "base.toml"', 'base = "nowhere.toml"'), ("not found", "nowhere.toml")),
    "sweep executor": ("sweep", ("workers = 1", 'executor = "slurm"'), ("executor", "'slurm'")),
    "sweep workers zero": ("sweep", ("workers = 1", "workers = 0"), ("workers", "0")),
    "sweep heatmap axis": ("sweep", ("workers = 1", 'workers = 1\n[heatmap]\nx = "speed"\ny = "mu_ratio"\n'
                                     'values = ["lag_angle_deg"]'), ("heatmap.x", "'speed'")),
    "sweep cli workers": ("sweep-argv", ["--workers", "-1"], ("workers", "-1")),
    "sweep figure folder": ("sweep-argv", ["--figure", "{tmp}/no/such/dir/f.png"], ("--figure", "f.png")),
}


def prepare(kind, payload, tmp):
    """Write the inputs of one table entry; returns the argv."""
    base = tmp / "base.toml"
    out = tmp / "out"
    text = BASE
    if kind == "scenario":
        text = edit(BASE, *payload)
    base.write_bytes(payload if kind == "bytes" else text.encode())
    if kind == "argv":
        return [a.format(tmp=tmp, out=out, base=base) for a in payload]
    if kind == "commands":
        (tmp / "plan.json").write_text(payload)
        return ["simulate", str(base), "--out", str(out), "--commands", str(tmp / "plan.json")]
    if kind.startswith("sweep"):
        sweep = edit(SWEEP, *payload) if kind == "sweep" else SWEEP
        (tmp / "sweep.toml").write_text(sweep)
        extra = [a.format(tmp=tmp) for a in payload] if kind == "sweep-argv" else []
        return ["sweep", str(tmp / "sweep.toml"), "--out", str(out), *extra]
    return ["simulate", str(base), "--out", str(out)]


def test_the_table_has_at_least_30_cases():
    assert len(BAD_INPUTS) >= 30


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_is_rejected_before_any_work(name, tmp_path, capsys):
    kind, payload, fragments = BAD_INPUTS[name]
    argv = prepare(kind, payload, tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    rc = main(argv)
    captured = capsys.readouterr()
    assert rc == EXIT_BAD_INPUT
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pushplan: error: "), captured.err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "out").exists()
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before  # nothing written


def test_bad_input_in_a_real_process_exits_2_without_traceback(tmp_path):
    (tmp_path / "bad.toml").write_text(edit(BASE, "poisson = 0.3", "poisson = 0.7"))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "pushplan.cli", "simulate", str(tmp_path / "bad.toml"),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == EXIT_BAD_INPUT
    assert proc.stderr.strip() == "pushplan: error: material.poisson must be < 0.5, got 0.7"
    assert not (tmp_path / "out").exists()


# ---- solver failure -----------------------------------------------------------

SOLVER_TABLE = "[solver]"  # edits go here: a failing [[load]] after the two good steps, or a solver limit
SOLVER_FAILURES = {
    # pressed by more than the block's height (a push of any length no longer
    # fails: the predictor slides the block along)
    "element inverted": ("[[load]]\ndz = -0.05\n[solver]", "element_inverted", 2),
    "not finite": ("[[load]]\ndx = 1e300\n[solver]", "not_finite", 2),
    "newton not converged": ("[solver]\nnewton_max_iter = 1", "newton_not_converged", 0),
    "contact not converged": ("[solver]\nlocal_max_iter = 1", "contact_not_converged", 0),
}


def strict_json(text):
    def reject(token):
        raise ValueError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=reject)


def check_failed_run(out, expected_status, finished, newton_tol=1e-10):
    summary = strict_json((out / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert summary["failure"]["status"] == expected_status and summary["failure"]["message"]
    assert summary["failure"]["step"] == finished + 1
    assert len(summary["steps"]) == finished
    for s in summary["steps"]:  # never a non-converged step reported as done
        assert s["converged"] and s["newton_residual"] <= newton_tol
    with np.load(out / "fields.npz") as fields:
        assert (fields["displacement"].shape[0] if "displacement" in fields else 0) == finished
    return summary


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the overflow is the point of "not finite"
@pytest.mark.parametrize("name", list(SOLVER_FAILURES))
def test_solver_failure_exits_3_with_a_valid_summary(name, tmp_path, capsys):
    addition, status, finished = SOLVER_FAILURES[name]
    (tmp_path / "s.toml").write_text(edit(BASE, SOLVER_TABLE, addition))
    out = tmp_path / "out"
    rc = main(["simulate", str(tmp_path / "s.toml"), "--out", str(out), "--quiet", "--no-recording"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_SOLVER_FAILURE
    assert len(err) == 1 and err[0].startswith("pushplan: solver failure:")
    check_failed_run(out, status, finished)


def test_a_bug_inside_a_run_is_not_reported_as_bad_input_or_solver_failure(tmp_path, monkeypatch):
    """A ValueError raised by a broken internal function is a bug: it propagates with
    its traceback (exit 1 from the console script), never exit 2 or 3."""
    module = importlib.import_module("fe_contact.stepping.sequence")  # the one stepping loop
    real_step, calls = module.step, []

    def broken_step(model, state, command, *args, **options):
        calls.append(command)
        if len(calls) == 2:
            raise ValueError("an internal bug")
        return real_step(model, state, command, *args, **options)

    monkeypatch.setattr(module, "step", broken_step)
    (tmp_path / "s.toml").write_text(BASE)
    with pytest.raises(ValueError, match="an internal bug"):
        main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet", "--no-recording"])


def test_a_bug_exits_1_with_its_traceback_in_a_real_process(tmp_path):
    (tmp_path / "s.toml").write_text(BASE)
    code = ("import sys, fe_contact.stepping.sequence as d\n"
            "def broken(*a, **k): raise ValueError('an internal bug')\n"
            "d.step = broken\n"
            "from pushplan.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", code, "simulate", str(tmp_path / "s.toml"), "--out",
                           str(tmp_path / "out"), "--quiet", "--no-recording"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr and "ValueError: an internal bug" in proc.stderr
    assert "pushplan: error" not in proc.stderr


# ---- determinism and long runs --------------------------------------------------


def without_wall_times(obj):
    if isinstance(obj, dict):
        return {k: without_wall_times(v) for k, v in obj.items() if k not in WALL_TIME_KEYS}
    if isinstance(obj, list):
        return [without_wall_times(v) for v in obj]
    return obj


def test_rerun_gives_identical_summary_numbers(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(edit(BASE, "direction_deg = 45.0", "direction_deg = 30.0\nrepeat = 3"))
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "a"), "--quiet", "--no-recording"]) == 0
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "pushplan.cli", "simulate", str(scenario), "--out",
                           str(tmp_path / "b"), "--quiet", "--no-recording"], capture_output=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    a, b = (strict_json((tmp_path / d / "summary.json").read_text()) for d in "ab")
    assert len(a["steps"]) == 4
    assert without_wall_times(a) == without_wall_times(b)


def long_push(tmp_path, elements, n_push, step_length, direction_deg, mu=(0.3, 0.1)):
    """Press 0.1 mm, then push ``n_push`` equal steps; checks every step and the
    final steady sliding against the elliptic law.  Returns the summary."""
    text = (BASE.replace("elements = [2, 2, 1]", f"elements = {list(elements)}")
            .replace("mu_x = 0.3", f"mu_x = {mu[0]}").replace("mu_y = 0.1", f"mu_y = {mu[1]}")
            .replace("distance = 0.32e-3", f"distance = {step_length}")
            .replace("direction_deg = 45.0", f"direction_deg = {direction_deg}\nrepeat = {n_push}"))
    (tmp_path / "long.toml").write_text(text)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "long.toml"), "--out", str(out), "--quiet", "--no-recording"]) == 0
    steps = strict_json((out / "summary.json").read_text())["steps"]
    assert len(steps) == n_push + 1
    for s in steps:
        assert s["converged"]
        assert s["equilibrium_error"] <= EQUILIBRIUM_TOL, (s["step"], s["equilibrium_error"])
        assert s["dissipation"] >= 0.0, (s["step"], s["dissipation"])
        assert all(math.isfinite(v) for v in s["lower_centroid"])
    # steady sliding: the lower face follows the push, and each step dissipates the
    # support function of the friction ellipse, N |diag(mu_x, mu_y) du| (uniform slip)
    a = math.radians(direction_deg)
    du = np.array([math.cos(a), math.sin(a)]) * step_length
    inc = np.subtract(steps[-1]["lower_centroid"], steps[-2]["lower_centroid"])[:2]
    assert np.linalg.norm(inc - du) <= STEADY_RTOL * step_length
    expected = steps[-1]["normal_force"] * float(np.linalg.norm(np.array(mu) * du))
    assert steps[-1]["dissipation"] == pytest.approx(expected, rel=STEADY_RTOL)
    return steps


def test_long_push_fast(tmp_path):
    steps = long_push(tmp_path, (3, 3, 1), 19, 0.04e-3, 30.0)
    assert steps[-1]["upper_centroid"][0] == pytest.approx(19 * 0.04e-3 * math.cos(math.radians(30.0)))


@pytest.mark.slow
def test_long_push_200_steps_on_the_planning_mesh(tmp_path):
    steps = long_push(tmp_path, (8, 8, 3), 199, 0.08e-3, 45.0, mu=(0.3, 0.05))
    assert len(steps) == 200


def test_the_cli_leaves_its_objects_to_the_os_at_exit(monkeypatch):
    """``main`` registers one exit handler however often it runs (a test process runs it
    hundreds of times), and the handler freezes the garbage collector's objects, so the
    interpreter's shutdown does not traverse them all (issue 32: 0.2-0.4 s of a run)."""
    import atexit
    import gc

    import pushplan.cli as cli

    registered = []
    monkeypatch.setattr(atexit, "register", lambda f: registered.append(f))
    monkeypatch.setattr(atexit, "unregister", lambda f: registered.remove(f) if f in registered else None)
    for _ in range(3):
        assert main(["--version"]) == 0
    assert registered == [cli._leave_objects_to_the_os]
    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    registered[0]()
    assert frozen == [True]


def test_a_run_exits_cleanly_with_its_outputs_after_the_frozen_shutdown(tmp_path):
    """A command as a process: exit status 0, its stdout complete and its files written,
    with the shutdown's collection skipped."""
    scenario = tmp_path / "s.toml"
    scenario.write_text(BASE)
    out = subprocess.run([sys.executable, "-c", "import sys; from pushplan.cli import main; "
                          "sys.exit(main())", "simulate", str(scenario), "--out", str(tmp_path / "o"),
                          "--no-recording"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.rstrip().splitlines()[-1].startswith("wrote ")
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["status"] == "completed"
