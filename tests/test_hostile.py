"""Hostile input (issue 23), table-driven: every case ends with exit 2, exactly one
line on stderr naming the key or the file, no traceback, and the good output already
in ``--out`` byte-identical afterwards (hidden files included), with no lock or
temporary left beside it.  Inputs: scenario, command files, plans, sweeps, MJCF,
paper, convergence and replay options, output paths, parser bombs and special files.
The FCLIB reader (a library, no command reads FCLIB) has its own table below."""

import hashlib
import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from pushplan.cli import EXIT_BAD_INPUT, main
from tiny_inputs import BASE, SWEEP  # the tiny scenario and sweep shared by the CLI tests

ROOT = Path(__file__).resolve().parents[1]
HUGE_MEMORY = "elements = [100, 100, 4]"  # passes validation, ~33 GB by the estimate


def edit(text, old, new):
    assert text.count(old) == 1, f"test table: {old!r} must occur once"
    return text.replace(old, new)


def sc(old, new, *fragments):
    return ("scenario", (old, new), fragments)


def plan_json(**changes):
    """A plan.json made for the BASE scenario with ``changes`` (dotted keys) to its scenario."""
    import tomllib

    scenario = tomllib.loads(BASE)
    for key, value in changes.items():
        table, k = key.split(".")
        scenario[table][k] = value
    return json.dumps({"scenario": scenario, "commands": [{"dz": -1e-4}, {"dx": 1e-4}]})


CASES = {
    # -- scenario values
    "size negative": sc("size = [0.02, 0.02, 0.01]", "size = [-0.02, 0.02, 0.01]", "block.size[0]"),
    "size nan": sc("size = [0.02, 0.02, 0.01]", "size = [0.02, nan, 0.01]", "block.size[1]", "nan"),
    "size huge list": sc("size = [0.02, 0.02, 0.01]", "size = [" + ", ".join(["0.02"] * 5000) + "]", "block.size"),
    "elements zero": sc("elements = [2, 2, 1]", "elements = [0, 2, 1]", "block.elements[0]"),
    "elements float": sc("elements = [2, 2, 1]", "elements = [2, 2, 1.5]", "block.elements[2]"),
    "elements over the cap": sc("elements = [2, 2, 1]", "elements = [1000, 1000, 10]", "block.elements"),
    "elements at the cap (memory)": sc("elements = [2, 2, 1]", "elements = [1000, 1000, 1]", "block.elements",
                                       "estimated memory", "--no-memory-check"),
    "elements 100x100x4 (memory)": sc("elements = [2, 2, 1]", HUGE_MEMORY, "block.elements", "estimated memory"),
    "quadrature 4": sc("quadrature = 2", "quadrature = 4", "block.quadrature"),
    "young zero": sc("young = 210e9", "young = 0.0", "material.young"),
    "young 1e308": sc("young = 210e9", "young = 1e400", "material.young", "inf"),
    "poisson 0.5": sc("poisson = 0.3", "poisson = 0.5", "material.poisson"),
    "mu_x negative": sc("mu_x = 0.3", "mu_x = -0.1", "friction.mu_x"),
    "mu_y inf": sc("mu_y = 0.1", "mu_y = inf", "friction.mu_y"),
    "mu_x string": sc("mu_x = 0.3", 'mu_x = "high"', "friction.mu_x"),
    "unknown key": sc("quadrature = 2", "quadrature = 2\ncolour = 1", "block.colour"),
    "unknown table": sc("[block]", "[blocks]", "blocks"),
    "missing material": sc("[material]\nyoung = 210e9\npoisson = 0.3\n", "", "[material]"),
    "load not array": sc("[[load]]\ndz = -1e-4\n[[load]]\ndistance = 0.32e-3\ndirection_deg = 45.0",
                         "[load]\ndz = -1e-4", "load"),
    "turn 360 in one step": sc("direction_deg = 45.0", "direction_deg = 45.0\ndtheta_deg = 360.0",
                               "load[1].dtheta_deg", "360"),
    "turn -180 in one step": sc("direction_deg = 45.0", "direction_deg = 45.0\ndtheta_deg = -180.0",
                                "load[1].dtheta_deg", "-180"),
    "repeat huge": sc("direction_deg = 45.0", "direction_deg = 45.0\nrepeat = 100000000", "load[1].repeat"),
    "local_method unknown": sc('local_method = "newton"', 'local_method = "magic"', "solver.local_method"),
    "newton_tol negative": sc('local_method = "newton"', "newton_tol = -1.0", "solver.newton_tol"),
    "name not string": sc('name = "tiny"', "name = 5", "name"),
    "no load steps": sc("[[load]]\ndz = -1e-4\n[[load]]\ndistance = 0.32e-3\ndirection_deg = 45.0", "",
                        "nothing to simulate", "base.toml"),
    # -- scenario files
    "malformed toml": sc("size = [0.02, 0.02, 0.01]", "size = [0.02, 0.02,", "malformed TOML", "base.toml"),
    "not utf-8": ("bytes", b'name = "\xff\xfe"\n', ("malformed TOML", "base.toml")),
    "nested arrays bomb": ("bytes", b"x = " + b"[" * 5000 + b"]" * 5000 + b"\n", ("nesting deeper", "base.toml")),
    "inline tables bomb": ("bytes", b"x = " + b"{a = " * 2000 + b"1" + b"}" * 2000 + b"\n",
                           ("nesting deeper", "base.toml")),
    "dotted key bomb": ("bytes", b"a" + b".a" * 20000 + b" = 1\n", ("dotted key", "base.toml")),
    "table header bomb": ("bytes", b"[" + b"a." * 3000 + b"a]\n", ("dotted key", "base.toml")),
    "file over 4 MiB": ("bytes", BASE.encode() + b"#" * (5 * 2**20) + b"\n", ("larger than", "base.toml")),
    "scenario /dev/zero": ("argv", ["simulate", "/dev/zero", "--out", "{out}"], ("not a regular file", "/dev/zero")),
    "scenario fifo": ("argv", ["simulate", "{tmp}/fifo.toml", "--out", "{out}"], ("not a regular file", "fifo.toml")),
    "scenario a folder": ("argv", ["simulate", "{tmp}", "--out", "{out}"], ("a folder",)),
    "scenario missing": ("argv", ["simulate", "{tmp}/missing.toml", "--out", "{out}"], ("not found", "missing.toml")),
    # -- command files and plans
    "commands deeply nested": ("commands", '{"commands": ' + "[" * 100000 + "]" * 100000 + "}",
                               ("nesting deeper", "plan.json")),
    "commands malformed": ("commands", '{"commands": [', ("cannot read commands file", "plan.json")),
    "commands a list": ("commands", "[1, 2]", ("plan.json", "'commands' list")),
    "commands bad value": ("commands", '{"commands": [{"dx": "far"}]}', ("commands[0].dx",)),
    "commands NaN": ("commands", '{"commands": [{"dx": NaN}]}', ("commands[0].dx", "nan")),
    "commands turn 360": ("commands", '{"commands": [{"dtheta_deg": 360}]}', ("commands[0].dtheta_deg", "360")),
    "commands unknown key": ("commands", '{"commands": [{"dw": 1}]}', ("commands[0].dw",)),
    "commands empty": ("commands", '{"commands": []}', ("nothing to simulate", "plan.json")),
    "commands /dev/zero": ("argv", ["simulate", "{base}", "--out", "{out}", "--commands", "/dev/zero"],
                           ("not a regular file", "/dev/zero")),
    "plan for other friction": ("commands", plan_json(**{"friction.mu_y": 0.2}),
                                ("made for another scenario", "friction.mu_y", "--force")),
    "plan for other block": ("commands", plan_json(**{"block.size": [0.03, 0.02, 0.01]}),
                             ("made for another scenario", "block.size")),
    "plan for other material": ("commands", plan_json(**{"material.young": 1e6}),
                                ("made for another scenario", "material.young")),
    # -- output paths
    "out under a file": ("argv", ["simulate", "{base}", "--out", "{base}/sub"], ("cannot create output folder", "sub")),
    "export-fclib is a file": ("argv", ["simulate", "{base}", "--out", "{out}", "--export-fclib", "{base}"],
                               ("not a folder", "base.toml")),
    "out locked by another run": ("locked", ["simulate", "{base}", "--out", "{out}"], ("in use", "out")),
    # -- sweeps
    "sweep negative mu": ("sweep", ('"friction.mu_y" = [0.1, 0.2]', '"friction.mu_y" = [0.1, -0.2]'),
                          ("friction.mu_y", "-0.2")),
    "sweep unknown key": ("sweep", ('"friction.mu_y"', '"friction.mu_z"'), ("friction.mu_z",)),
    "sweep empty grid list": ("sweep", ("[0.1, 0.2]", "[]"), ("grid.friction.mu_y",)),
    "sweep executor": ("sweep", ("workers = 1", 'executor = "slurm"'), ("executor", "'slurm'")),
    "sweep workers zero": ("sweep", ("workers = 1", "workers = 0"), ("workers", "0")),
    "sweep missing base": ("sweep", ('base = "base.toml"', 'base = "nowhere.toml"'), ("not found", "nowhere.toml")),
    "sweep base /dev/zero": ("sweep", ('base = "base.toml"', 'base = "/dev/zero"'), ("not a regular file",)),
    "sweep nesting bomb": ("sweep", ("workers = 1", "workers = 1\nx = " + "[" * 3000 + "]" * 3000),
                           ("nesting deeper", "sweep.toml")),
    "sweep memory": ("sweep", ('"friction.mu_y" = [0.1, 0.2]', '"block.elements" = [[100, 100, 4]]'),
                     ("block.elements", "estimated memory")),
    "sweep cli workers": ("sweep-argv", ["--workers", "-1"], ("workers", "-1")),
    "sweep figure folder": ("sweep-argv", ["--figure", "{tmp}/no/such/dir/f.png"], ("--figure", "f.png")),
    "sweep scheduler refused": ("sweep-argv", ["--scheduler", "tcp://127.0.0.1:1"], ("--scheduler", "127.0.0.1:1")),
    # -- replay, plan, paper, convergence
    "replay a text file": ("argv", ["replay", "{base}", "--out", "{out}"], ("replay needs", "base.toml")),
    "replay plan of other scenario": ("replay-plan", plan_json(**{"friction.mu_x": 0.5}),
                                      ("made for another scenario", "friction.mu_x")),
    "plan without [plan]": ("argv", ["plan", "{base}", "--out", "{out}"], ("plan",)),
    "paper elements zero": ("argv", ["paper", "--out", "{out}", "--elements", "0", "2", "1"], ("elements",)),
    "paper memory": ("argv", ["paper", "--out", "{out}", "--elements", "200", "200", "20"],
                     ("--elements", "estimated memory")),
    "convergence levels 2": ("argv", ["convergence", "{base}", "--levels", "2", "--out", "{out}"], ("--levels",)),
    "convergence ratio 1": ("argv", ["convergence", "{base}", "--levels", "3", "--ratio", "1", "--out", "{out}"],
                            ("--ratio",)),
    "convergence memory": ("argv", ["convergence", "{base}", "--levels", "3", "--elements", "60", "60", "2",
                                    "--out", "{out}"], ("finest mesh", "estimated memory")),
    # -- MJCF: what MuJoCo compiled, not what it fell back to
    "mjcf friction nan": ("mjcf", "nan 0.1", ("block_floor", "nan")),
    "mjcf friction negative": ("mjcf", "-0.3 0.1", ("block_floor", "-0.3")),
    "mjcf friction inf": ("mjcf", "0.3 inf", ("block_floor", "inf")),
}


def snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def good_output(tmp_path_factory):
    """A complete simulate output (summary, fields, recording) to put in every --out."""
    tmp = tmp_path_factory.mktemp("good")
    (tmp / "base.toml").write_text(BASE)
    assert main(["simulate", str(tmp / "base.toml"), "--out", str(tmp / "out"), "--quiet"]) == 0
    return tmp / "out"


def prepare(kind, payload, tmp: Path) -> list[str]:
    base, out = tmp / "base.toml", tmp / "out"
    base.write_bytes(payload if kind == "bytes" else (edit(BASE, *payload) if kind == "scenario" else BASE).encode())
    if kind in ("argv", "locked"):
        os.mkfifo(tmp / "fifo.toml")
        return [a.format(tmp=tmp, out=out, base=base) for a in payload]
    if kind == "commands":
        (tmp / "plan.json").write_text(payload)
        return ["simulate", str(base), "--out", str(out), "--commands", str(tmp / "plan.json")]
    if kind == "replay-plan":
        (tmp / "plan.json").write_text(payload)
        return ["replay", str(tmp / "plan.json"), "--scenario", str(base), "--out", str(out)]
    if kind.startswith("sweep"):
        (tmp / "sweep.toml").write_text(edit(SWEEP, *payload) if kind == "sweep" else SWEEP)
        extra = [a.format(tmp=tmp) for a in payload] if kind == "sweep-argv" else []
        return ["sweep", str(tmp / "sweep.toml"), "--out", str(out), *extra]
    if kind == "mjcf":
        text = (ROOT / "scenarios" / "mujoco_push.xml").read_text()
        start = text.index('friction="', text.index('<pair name="block_floor"'))
        end = text.index('"', start + len('friction="'))
        (tmp / "scene.xml").write_text(text[:start] + f'friction="{payload} 0.005 0.0001 0.0001"' + text[end + 1:])
        (tmp / "cmds.json").write_text('{"commands": [{"dz": -1e-4}]}')
        return ["mujoco", "compare", str(tmp / "scene.xml"), "--commands", str(tmp / "cmds.json"), "--out", str(out)]
    return ["simulate", str(base), "--out", str(out)]


def test_the_table_has_at_least_60_cases():
    assert len(CASES) >= 60


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_input_is_one_line_exit_2_and_leaves_the_output(name, tmp_path, capsys, good_output, monkeypatch):
    kind, payload, fragments = CASES[name]
    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT into the current folder
    shutil.copytree(good_output, tmp_path / "out")
    argv = prepare(kind, payload, tmp_path)
    before = snapshot(tmp_path / "out")
    assert before  # a real previous output to protect
    lock = None
    if kind == "locked":
        from pushplan.outputs.transaction import OutputLock

        lock = OutputLock(tmp_path / "out")
        lock.acquire()
    try:
        rc = main(argv)
    finally:
        if lock is not None:
            lock.release()
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT, captured.err
    assert len(lines) == 1 and lines[0].startswith("pushplan: error: "), captured.err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert "Traceback" not in captured.err + captured.out
    assert snapshot(tmp_path / "out") == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.")] == []


# ---- FCLIB reader: datasets present and shapes declared right, before any allocation ----


def fclib_file(path, nc=2, drop=(), replace=None):
    """A valid local FCLIB problem of ``nc`` contacts, with datasets dropped or replaced."""
    from fe_contact.io.fclib import write_local_problem

    W = np.eye(3 * nc) + 0.1
    write_local_problem(path, W, np.ones((nc, 3)), 0.3, 0.3)
    with h5py.File(path, "r+") as f:
        for name in drop:
            del f[name]
        for name, data in (replace or {}).items():
            del f[name]
            f.create_dataset(name, data=data)
    return path


FCLIB_CASES = {
    "q missing": ({"drop": ["fclib_local/vectors/q"]}, "fclib_local/vectors/q is missing"),
    "mu missing": ({"drop": ["fclib_local/vectors/mu"]}, "fclib_local/vectors/mu is missing"),
    "W p missing": ({"drop": ["fclib_local/W/p"]}, "fclib_local/W/p is missing"),
    "spacedim missing": ({"drop": ["fclib_local/spacedim"]}, "fclib_local/spacedim is missing"),
    "empty m": ({"replace": {"fclib_local/W/m": np.zeros(0, np.int32)}}, "fclib_local/W/m must hold one number"),
    "huge W declared": ({"replace": {"fclib_local/W/m": np.array([10**9]), "fclib_local/W/n": np.array([10**9])}},
                        "declared (1000000000, 1000000000)"),
    "q mis-shaped": ({"replace": {"fclib_local/vectors/q": np.ones(7)}}, "vectors/q has shape (7,)"),
    "q for 3 contacts, mu for 2": ({"replace": {"fclib_local/vectors/q": np.ones(9)}}, "vectors/q has shape (9,)"),
}


@pytest.mark.parametrize("name", list(FCLIB_CASES))
def test_fclib_reader_checks_before_reading(name, tmp_path):
    from fe_contact.io.fclib import read_local_problem

    options, fragment = FCLIB_CASES[name]
    path = fclib_file(tmp_path / "p.hdf5", **options)
    with pytest.raises(ValueError) as info:
        read_local_problem(path)
    assert fragment in str(info.value) and "p.hdf5" in str(info.value)


def test_fclib_reader_refuses_a_small_file_declaring_a_huge_problem(tmp_path):
    """10^6 contacts declared by a file of a few kB: refused by the contact cap, nothing read."""
    from fe_contact.io.fclib import read_local_problem

    path = fclib_file(tmp_path / "p.hdf5")
    with h5py.File(path, "r+") as f:
        for name in ("fclib_local/vectors/q", "fclib_local/vectors/mu"):
            del f[name]
        f.create_dataset("fclib_local/vectors/mu", shape=(10**6,), dtype=float, fillvalue=0.3)
        f.create_dataset("fclib_local/vectors/q", shape=(3 * 10**6,), dtype=float)
    assert path.stat().st_size < 100_000
    with pytest.raises(ValueError, match="1000000 contacts"):
        read_local_problem(path)


# ---- overrides and limits that are not errors ---------------------------------------


def test_force_runs_a_plan_made_for_another_scenario(tmp_path, capsys):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "plan.json").write_text(plan_json(**{"friction.mu_y": 0.2}))
    argv = ["simulate", str(tmp_path / "base.toml"), "--out", str(tmp_path / "out"), "--quiet", "--no-recording",
            "--commands", str(tmp_path / "plan.json")]
    assert main(argv) == EXIT_BAD_INPUT
    assert main([*argv, "--force"]) == 0
    assert len(json.loads((tmp_path / "out" / "summary.json").read_text())["steps"]) == 2


def test_the_memory_check_can_be_overridden_and_counts_parallel_cases():
    from pushplan.config.budget import available_memory, check_memory, estimate_memory

    huge = (100, 100, 4)
    assert check_memory(huge, 2, override=True) == estimate_memory(huge, 2) > 30e9
    assert check_memory((2, 2, 1), 2, copies=3) == 3 * estimate_memory((2, 2, 1), 2)
    limit = available_memory()
    assert limit is None or limit > estimate_memory((2, 2, 1), 2)


def test_long_grid_values_give_short_unique_case_ids(tmp_path):
    from pushplan.config.sweep import MAX_CASE_ID, load_sweep

    (tmp_path / "base.toml").write_text(BASE)
    sizes = [[0.02 + i * 1e-13, 0.020000000000000004, 0.010000000000000002] for i in range(3)]
    (tmp_path / "sweep.toml").write_text(
        f'base = "base.toml"\n[grid]\n"block.size" = {json.dumps(sizes)}\n"friction.mu_y" = [0.1000000000000001]\n'
        f'"material.young" = [210000000000.00003]\n"friction.mu_x" = [0.30000000000000004]\n')
    cases = load_sweep(tmp_path / "sweep.toml").cases
    ids = [c.case_id for c in cases]
    assert len(set(ids)) == 3 and all(len(i) <= MAX_CASE_ID for i in ids)
    assert all(len("_".join(f"{k}={v}" for k, v in c.params.items())) > MAX_CASE_ID for c in cases)
    for i in ids:  # a real folder name
        (tmp_path / "cases" / i).mkdir(parents=True)


def test_numpy_warnings_do_not_precede_a_one_line_outcome(tmp_path):
    """A push to 1e300 m overflows inside the model: exit 3 with the solver's one line,
    not numpy's RuntimeWarnings first (a real process: pytest records warnings itself)."""
    import subprocess
    import sys

    (tmp_path / "s.toml").write_text(edit(BASE, "[solver]", "[[load]]\ndx = 1e300\n[solver]"))
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "pushplan.cli", "simulate", str(tmp_path / "s.toml"), "--out",
                           str(tmp_path / "out"), "--quiet", "--no-recording"], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 3
    assert proc.stderr.strip().splitlines() == [
        "pushplan: solver failure: non-finite internal force at Newton iteration 0"]
