"""Output paths (issue 34, root causes 4 and 5): every command that writes goes through
the one transaction and lock (``pushplan/outputs/transaction.py``).  For each command
and each output option: a symbolic link (to a folder, dangling), a name too long for the
transaction's siblings, a read-only target, a target locked by another run, and for
single files a missing folder and an existing folder: exit 2, one line, the target
(and the link's target) unchanged, no sibling left."""

import hashlib
import os
import stat
from pathlib import Path

import pytest

from pushplan.cli import EXIT_BAD_INPUT, main
from pushplan.outputs.transaction import OutputLock
from tiny_inputs import BASE, OBSERVATIONS, PLAN

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "scenarios" / "mujoco_push.xml"
COMMANDS = '{"commands": [{"dz": -1e-4}]}'
SWEEP = """base = "s.toml"
workers = 1
[grid]
"friction.mu_y" = [0.1, 0.2]
"friction.mu_x" = [0.3, 0.4]
[heatmap]
x = "friction.mu_y"
y = "friction.mu_x"
values = ["twist_deg"]
"""

# command: argv with {out} the folder (or file) under test
FOLDER_COMMANDS = {
    "simulate": ["simulate", "{tmp}/s.toml", "--out", "{out}"],
    "simulate --export-fclib": ["simulate", "{tmp}/s.toml", "--out", "{tmp}/sim", "--export-fclib", "{out}"],
    "replay": ["replay", "{tmp}/c.json", "--scenario", "{tmp}/s.toml", "--out", "{out}"],
    "plan": ["plan", "{tmp}/p.toml", "--out", "{out}"],
    "paper": ["paper", "--out", "{out}", "--elements", "2", "2", "1"],
    "demo": ["demo", "--out", "{out}"],
    "convergence": ["convergence", "{tmp}/s.toml", "--levels", "3", "--out", "{out}"],
    "identify": ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
    "closed-loop": ["closed-loop", "{tmp}/p.toml", "--truth", "{tmp}/p.toml", "--out", "{out}"],
    "mujoco compare": ["mujoco", "compare", str(XML), "--commands", "{tmp}/c.json", "--out", "{out}"],
    "mujoco cosim": ["mujoco", "cosim", str(XML), "--commands", "{tmp}/c.json", "--out", "{out}"],
    "sweep": ["sweep", "{tmp}/w.toml", "--out", "{out}"],
}
FILE_COMMANDS = {
    "simulate --observations": ["simulate", "{tmp}/s.toml", "--out", "{tmp}/sim", "--observations", "{out}"],
    "sweep --figure": ["sweep", "{tmp}/w.toml", "--out", "{tmp}/sw", "--figure", "{out}"],
    "mujoco export": ["mujoco", "export", str(XML), "--commands", "{tmp}/c.json", "--out", "{out}"],
}
FILE_SUFFIX = {"simulate --observations": ".csv", "sweep --figure": ".png", "mujoco export": ".xml"}
FOLDER_HAZARDS = ("symlink", "dangling symlink", "long name", "long path", "read-only", "locked")
FILE_HAZARDS = (*FOLDER_HAZARDS, "missing folder", "existing folder")
FRAGMENT = {"symlink": "symbolic link", "dangling symlink": "dangling", "long name": "too long",
            "long path": "the path", "read-only": "read-only", "locked": "in use", "missing folder": "does not exist",
            "existing folder": "is a folder"}


def snapshot(path: Path) -> dict:
    if path.is_file():
        return {"": hashlib.sha256(path.read_bytes()).hexdigest()}
    return {p.relative_to(path).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(path.rglob("*")) if p.is_file()}


def hazard_path(tmp: Path, hazard: str, suffix: str, folder: bool) -> tuple[Path, Path]:
    """(the path given to the command, the real target whose content must not change)."""
    real = tmp / ("real" + suffix)
    if folder:
        real.mkdir()
        (real / "keep.json").write_text('{"previous": "output"}')
    else:
        real.write_text("previous output")
    if hazard == "symlink":
        (tmp / ("link" + suffix)).symlink_to(real)
        return tmp / ("link" + suffix), real
    if hazard == "dangling symlink":
        (tmp / ("link" + suffix)).symlink_to(tmp / "nowhere")
        return tmp / ("link" + suffix), real
    if hazard == "long name":
        return tmp / ("a" * 240 + suffix), real
    if hazard == "long path":  # 4019 bytes: the files inside it would pass PATH_MAX
        return tmp / ("/".join(["d" * 200] * 20) + suffix), real
    if hazard == "read-only":
        real.chmod(0o555 if folder else 0o444)
        return real, real
    if hazard == "missing folder":
        return tmp / "no" / "such" / ("f" + suffix), real
    if hazard == "existing folder":
        (tmp / ("dir" + suffix)).mkdir()
        return tmp / ("dir" + suffix), real
    return real, real  # locked


CASES = [(c, h, True) for c in FOLDER_COMMANDS for h in FOLDER_HAZARDS] + \
        [(c, h, False) for c in FILE_COMMANDS for h in FILE_HAZARDS]


@pytest.mark.parametrize("command,hazard,folder", CASES, ids=[f"{c}-{h}" for c, h, _ in CASES])
def test_a_hazardous_output_path_is_one_line_exit_2(command, hazard, folder, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, text in (("s.toml", BASE), ("p.toml", PLAN), ("o.csv", OBSERVATIONS), ("c.json", COMMANDS),
                       ("w.toml", SWEEP)):
        (tmp_path / name).write_text(text)
    suffix = "" if folder else FILE_SUFFIX[command]
    path, real = hazard_path(tmp_path, hazard, suffix, folder)
    before = snapshot(real)
    argv = [a.format(tmp=tmp_path, out=path) for a in (FOLDER_COMMANDS if folder else FILE_COMMANDS)[command]]
    lock = OutputLock(path) if hazard == "locked" else None
    if lock:
        lock.acquire()
    try:
        rc = main(argv)
    finally:
        if lock:
            lock.release()
        if hazard == "read-only":
            real.chmod(stat.S_IRWXU)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT and len(err) == 1 and err[0].startswith("pushplan: error: "), err
    assert FRAGMENT[hazard] in err[0], err[0]
    assert snapshot(real) == before
    if hazard in ("symlink", "dangling symlink"):
        assert path.is_symlink()
    hidden = [p.name for p in tmp_path.iterdir() if p.name.startswith(".") and not p.name.endswith(".lock")]
    assert hidden == []
    assert not os.path.lexists(tmp_path / "no") and not os.path.lexists(tmp_path / ("d" * 200))
