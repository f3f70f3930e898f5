"""Issue 34, root cause 0: a Python warning raised during a command must not hang it.

``pushplan.cli.main`` holds warnings back while a command runs and shows them after
it; showing them inside ``catch_warnings(record=True)`` recorded each one again and the
loop never ended (787 MB in 5 s).  Every command path is driven here with its command
function replaced by one that warns, in one child process with a deadline (a hang
fails the test instead of stalling the suite)."""

import json
import os
import subprocess
import sys
from pathlib import Path

from tiny_inputs import BASE

ROOT = Path(__file__).resolve().parents[1]

# every leaf command, with the least argv its parser accepts (the files need not exist:
# the command function is replaced)
ARGV = {
    ("simulate",): ["simulate", "s.toml", "--out", "o"],
    ("demo",): ["demo", "--out", "o"],
    ("paper",): ["paper", "--out", "o"],
    ("plan",): ["plan", "s.toml", "--out", "o"],
    ("replay",): ["replay", "p.json", "--out", "o"],
    ("view",): ["view", "r.rrd"],
    ("mujoco", "import"): ["mujoco", "import", "s.xml"],
    ("mujoco", "compare"): ["mujoco", "compare", "s.xml", "--out", "o"],
    ("mujoco", "cosim"): ["mujoco", "cosim", "s.xml", "--out", "o"],
    ("mujoco", "export"): ["mujoco", "export", "s.xml", "--out", "o.xml"],
    ("sweep",): ["sweep", "w.toml", "--out", "o"],
    ("convergence",): ["convergence", "s.toml", "--levels", "3", "--out", "o"],
    ("identify",): ["identify", "s.toml", "--observations", "o.csv", "--out", "o"],
    ("closed-loop",): ["closed-loop", "s.toml", "--truth", "t.toml", "--out", "o"],
    ("serve",): ["serve"],
}

CHILD = r"""
import argparse, contextlib, io, json, sys, warnings
from pushplan.cli import build_parser, main
from pushplan.errors import InputWarning

ARGV = json.loads(sys.argv[1])

def leaves(parser, prefix=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from leaves(sub, prefix + (name,))
            return
    yield prefix, parser._defaults["func"]

results = {}
for path, func in leaves(build_parser()):
    for status in (0, 2, 3):
        def warning_command(args, status=status):
            warnings.warn("numpy-like overflow", RuntimeWarning)
            warnings.warn("modulus in MPa?", InputWarning)
            print("done")
            return status
        module = sys.modules[func.__module__]
        setattr(module, func.__name__, warning_command)
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            rc = main(ARGV[" ".join(path)])
        setattr(module, func.__name__, func)
        results[f"{' '.join(path)} {status}"] = [rc, err.getvalue()]
print(json.dumps(results))
"""


def _env():
    return {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "",
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def test_a_warning_in_every_command_is_shown_once_and_the_command_exits():
    argv = {" ".join(k): v for k, v in ARGV.items()}
    proc = subprocess.run([sys.executable, "-c", CHILD, json.dumps(argv)], capture_output=True, text=True,
                          timeout=60, env=_env())
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert {k.rsplit(" ", 1)[0] for k in results} == set(argv), "a command without an ARGV row"
    for key, (rc, err) in results.items():
        status = int(key.rsplit(" ", 1)[1])
        assert rc == status, (key, err)
        # the input warning once, except before bad input's one line; the other only after a success
        assert err.count("pushplan: warning: modulus in MPa?") == (0 if status == 2 else 1), (key, err)
        assert err.count("numpy-like overflow") == (1 if status == 0 else 0), (key, err)


def test_convergence_with_a_matplotlib_warning_exits(tmp_path):
    """The reported case: a tiny study at ratio 1.5 prints its table and "wrote ..."; it
    must exit 0 (it hung), and the figure asks for no legend it has no labels for (issue 43:
    matplotlib's "No artists with labels" warning is gone)."""
    (tmp_path / "s.toml").write_text(BASE)
    proc = subprocess.run([sys.executable, "-m", "pushplan.cli", "convergence", str(tmp_path / "s.toml"),
                           "--levels", "3", "--ratio", "1.5", "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120, env=_env(), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout
    assert "No artists with labels" not in proc.stderr, proc.stderr
