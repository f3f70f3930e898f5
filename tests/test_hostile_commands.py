"""Hostile input, round 3 (issue 34): the commands added since round 2 (identify,
closed-loop, mujoco, convergence, plan's options) and the less travelled inputs.
Every case: exit 2, exactly one ``pushplan: error:`` line naming the key, option or
file, no traceback, and the good output already in ``--out`` byte-identical (no lock,
no sibling left).  Root causes: numbers a float cannot hold, loops without a budget,
models built without the memory budget, observation files, argparse usage errors."""

import hashlib
import json
from pathlib import Path

import pytest

from pushplan.cli import EXIT_BAD_INPUT, main
from tiny_inputs import BASE, OBSERVATIONS, PLAN

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "scenarios" / "mujoco_push.xml"
HUGE = "10" + "0" * 400  # an integer no float holds
MUJOCO = f'\n[mujoco]\nscene = "{XML}"\n'


def edit(text, old, new):
    assert text.count(old) == 1, f"test table: {old!r} must occur once"
    return text.replace(old, new)


def files(**kw):
    return kw


# name: (files to write {name: text}, argv (formatted with {tmp}, {out}), fragments of the one line)
CASES = {
    # -- 1. numbers that are not numbers yet
    "400-digit young": (files(s=edit(BASE, "young = 210e9", f"young = {HUGE}")),
                        ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["material.young", "float"]),
    "5000-digit integer in a scenario": (files(s=edit(BASE, "quadrature = 2", "quadrature = 1" + "0" * 5000)),
                                         ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["malformed TOML", "s"]),
    "400-digit command": (files(s=BASE, c='{"commands": [{"dx": ' + HUGE + "}]}"),
                          ["simulate", "{tmp}/s.toml", "--out", "{out}", "--commands", "{tmp}/c.json"], ["commands[0].dx"]),
    "5000-digit command": (files(s=BASE, c='{"commands": [{"dx": 1' + "0" * 5000 + "}]}"),
                           ["simulate", "{tmp}/s.toml", "--out", "{out}", "--commands", "{tmp}/c.json"], ["commands file", "c"]),
    "400-digit observation json": (files(s=BASE, o='{"observations": [{"dx": 0, "dy": 0, "dz": ' + HUGE
                                                   + ', "dtheta_deg": 0, "lower_x": 0}]}'),
                                   ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.json", "--out", "{out}"],
                                   ["row 1 column dz"]),
    "verification ratio nan": (files(s=PLAN), ["plan", "{tmp}/s.toml", "--out", "{out}", "--verification-error",
                                               "--verification-ratio", "nan"], ["--verification-ratio", "nan"]),
    "verification ratio 0.5": (files(s=PLAN), ["plan", "{tmp}/s.toml", "--out", "{out}", "--verification-ratio", "0.5"],
                               ["--verification-ratio", "0.5"]),
    "convergence ratio 1e308": (files(s=BASE), ["convergence", "{tmp}/s.toml", "--levels", "3", "--ratio", "1e308",
                                                "--out", "{out}"], ["--ratio"]),
    "settle time 1e308": (files(s=BASE + MUJOCO + "settle_time = 1e308\n"),
                          ["mujoco", "compare", "{tmp}/s.toml", "--out", "{out}"], ["mujoco.settle_time"]),
    "control period 1e308 (option)": (files(s=BASE + MUJOCO), ["mujoco", "cosim", "{tmp}/s.toml", "--out", "{out}",
                                                               "--control-period", "1e308"], ["--control-period"]),
    "gripper 1e300 N/m": (files(s=BASE + "[gripper]\nstiffness_xy = 1e300\nstiffness_yaw = 1e300\n"),
                          ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["gripper.stiffness_xy"]),
    "pose noise 1e-300": (files(s=BASE, o=OBSERVATIONS), ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv",
                                                          "--out", "{out}", "--pose-noise", "1e-300"], ["--pose-noise"]),
    "force noise inf": (files(s=PLAN, t=PLAN), ["closed-loop", "{tmp}/s.toml", "--truth", "{tmp}/t.toml", "--out", "{out}",
                                                "--force-noise", "inf"], ["--force-noise", "inf"]),
    # -- 2. budgets on every loop a user can make long
    "newton_max_iter 1e9": (files(s=edit(BASE, 'local_method = "newton"', "newton_max_iter = 1000000000")),
                            ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["solver.newton_max_iter", "<="]),
    "newton_tol 1e-300": (files(s=edit(BASE, 'local_method = "newton"', "newton_tol = 1e-300")),
                          ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["solver.newton_tol"]),
    "local_max_iter 2^63-1": (files(s=edit(BASE, 'local_method = "newton"',
                                           'local_method = "uzawa"\nlocal_max_iter = 9223372036854775807')),
                              ["simulate", "{tmp}/s.toml", "--out", "{out}"], ["solver.local_max_iter"]),
    "plan steps 1e6": (files(s=edit(PLAN, "steps = 2", "steps = 1000000")), ["plan", "{tmp}/s.toml", "--out", "{out}"],
                       ["plan.steps"]),
    "max_rollouts 1e9": (files(s=PLAN + "max_rollouts = 1000000000\n"), ["plan", "{tmp}/s.toml", "--out", "{out}"],
                         ["plan.max_rollouts"]),
    "plan tolerance 1e308": (files(s=edit(PLAN, "max_step = 1e-4", "max_step = 1e-4\ntolerance = 1e308")),
                             ["plan", "{tmp}/s.toml", "--out", "{out}"], ["plan.tolerance"]),
    "plan max_step 1e-320": (files(s=edit(PLAN, "max_step = 1e-4", "max_step = 1e-320")),
                             ["plan", "{tmp}/s.toml", "--out", "{out}"], ["plan.max_step"]),
    "planning_quadrature 1": (files(s=edit(PLAN, "planning_quadrature = 2", "planning_quadrature = 1")),
                              ["plan", "{tmp}/s.toml", "--out", "{out}"], ["plan.planning_quadrature"]),
    "suggest 100000": (files(s=BASE, o=OBSERVATIONS), ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv",
                                                       "--out", "{out}", "--suggest", "100000"], ["--suggest"]),
    "levels 1e9": (files(s=BASE), ["convergence", "{tmp}/s.toml", "--levels", "1000000000", "--ratio", "1.0000000000001",
                                   "--out", "{out}"], ["--levels"]),
    "levels that do not refine": (files(s=BASE), ["convergence", "{tmp}/s.toml", "--levels", "3", "--ratio",
                                                  "1.0000000000001", "--out", "{out}"], ["not refinements"]),
    "flex points 200": (files(s=BASE + MUJOCO + "flex_points = [200, 200, 200]\n"),
                        ["mujoco", "compare", "{tmp}/s.toml", "--out", "{out}"], ["mujoco.flex_points[0]"]),
    "MuJoCo timestep 1e-9": (files(x=XML.read_text().replace("<size ", '<option timestep="1e-9"/><size ', 1),
                                   c='{"commands": [{"dz": -1e-4}]}'),
                             ["mujoco", "cosim", "{tmp}/x.xml", "--commands", "{tmp}/c.json", "--out", "{out}"],
                             ["timestep", "steps, more than"]),
    "150000 commands": (files(s=BASE, c='{"commands": [' + ",".join(['{"dx": 1e-9}'] * 150000) + "]}"),
                        ["simulate", "{tmp}/s.toml", "--out", "{out}", "--commands", "{tmp}/c.json"], ["150000 commands"]),
    "300000 observation rows": (files(s=BASE, o="dx,dy,dz,dtheta_deg,lower_x\n" + "0,0,0,0,0\n" * 300000),
                                ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                                ["o.csv", "rows"]),
    "sweep workers 1e6 (file)": (files(s=BASE, w='base = "s.toml"\nworkers = 1000000\n[grid]\n"friction.mu_y" = [0.1]\n'),
                                 ["sweep", "{tmp}/w.toml", "--out", "{out}"], ["workers"]),
    # -- 3. the memory budget before every model
    "cosim 300x300x1": (files(s=BASE + MUJOCO), ["mujoco", "cosim", "{tmp}/s.toml", "--out", "{out}",
                                                 "--elements", "300", "300", "1"], ["--elements", "estimated memory"]),
    "export 300x300x1": (files(s=BASE + MUJOCO), ["mujoco", "export", "{tmp}/s.toml", "--out", "{out}.xml",
                                                  "--elements", "300", "300", "1"], ["--elements", "estimated memory"]),
    "identify 300x300x1": (files(s=edit(BASE, "elements = [2, 2, 1]", "elements = [300, 300, 1]"), o=OBSERVATIONS),
                           ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                           ["block.elements", "estimated memory"]),
    "closed-loop truth 300x300x1": (files(s=PLAN, t=edit(PLAN, "\nelements = [2, 2, 1]", "\nelements = [300, 300, 1]")),
                                    ["closed-loop", "{tmp}/s.toml", "--truth", "{tmp}/t.toml", "--out", "{out}"],
                                    ["block.elements", "estimated memory"]),
    "planning elements 1000x1000x1": (files(s=edit(PLAN, "planning_elements = [2, 2, 1]",
                                                   "planning_elements = [1000, 1000, 1]")),
                                      ["plan", "{tmp}/s.toml", "--out", "{out}"],
                                      ["plan.planning_elements", "estimated memory"]),
    # -- 6. observation files
    "turn 720 in a row": (files(s=BASE, o=OBSERVATIONS.replace("0.00022627416997969522,0.0,0.0,",
                                                               "0.00022627416997969522,0.0,720,")),
                          ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                          ["row 2 column dtheta_deg", "720"]),
    "turn -360 in a row (plan --from)": (files(s=PLAN, o="dx,dy,dz,dtheta_deg,lower_x\n0,0,-1e-4,0,0\n0,0,0,-360,0\n"),
                                         ["plan", "{tmp}/s.toml", "--out", "{out}", "--from", "{tmp}/o.csv"],
                                         ["row 2 column dtheta_deg", "-360"]),
    "a 1 m push in a row (plan --from)": (files(s=PLAN, o="dx,dy,dz,dtheta_deg,lower_x,lower_y\n0,0,-1e-4,0,0,0\n"
                                                       "1.0,0,0,0,0,0\n"),
                                          ["plan", "{tmp}/s.toml", "--out", "{out}", "--from", "{tmp}/o.csv"],
                                          ["observations: row 2", "[1.0, 0.0, 0]", "plan.max_step = 0.0001"]),
    "a 3 deg turn in a row, max_dtheta_deg 0.5 (plan --from)": (
        files(s=edit(PLAN, "steps = 2", "steps = 2\nyaw_deg = 1.0\nmax_dtheta_deg = 0.5"),
              o="dx,dy,dz,dtheta_deg,lower_x,lower_y,lower_yaw_deg\n0,0,-1e-4,0,0,0,0\n0,0,0,3,0,0,0\n"),
        ["plan", "{tmp}/s.toml", "--out", "{out}", "--from", "{tmp}/o.csv"],
        ["observations: row 2", "3]", "turns 3 deg", "plan.max_dtheta_deg = 0.5"]),
    "commands-only observations": (files(s=BASE, o="dx,dy,dz,dtheta_deg\n0,0,-1e-4,0\n1e-4,0,0,0\n"),
                                   ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                                   ["commands only"]),
    "press and zero pushes": (files(s=BASE, o="dx,dy,dz,dtheta_deg,lower_x\n0,0,-1e-4,0,0\n"),
                              ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                              ["cannot determine"]),
    "200000-character field": (files(s=BASE, o="dx,dy,dz,dtheta_deg\n\"" + "1" * 200000 + "\",0,0,0\n"),
                               ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"], ["o.csv"]),
    "quoted multi-line field": (files(s=BASE, o='dx,dy,dz,dtheta_deg,lower_x\n0,0,-1e-4,0,0\n"1\n2",0,0,0,0\n'),
                                ["identify", "{tmp}/s.toml", "--observations", "{tmp}/o.csv", "--out", "{out}"],
                                ["row 2 column dx"]),
    "truth of another block": (files(s=PLAN, t=edit(edit(PLAN, "size = [0.02, 0.02, 0.01]", "size = [0.03, 0.02, 0.01]"),
                                                    "young = 210e9", "young = 2e6")),
                               ["closed-loop", "{tmp}/s.toml", "--truth", "{tmp}/t.toml", "--out", "{out}"],
                               ["--truth", "block.size", "another block"]),
    # -- 7. MJCF
    "mjcf over 4 MiB": (files(x=XML.read_text().replace("<mujoco", "<!--" + "x" * (5 * 2**20) + "-->\n<mujoco", 1)),
                        ["mujoco", "import", "{tmp}/x.xml"], ["larger than", "x"]),
    "mjcf nan friction in a default": (
        files(x=XML.read_text().replace("<worldbody>", '<default><default class="f"><pair friction="nan 0.3"/>'
                                        "</default></default><worldbody>", 1)),
        ["mujoco", "import", "{tmp}/x.xml"], ["<pair>", "nan", "x"]),
    "mjcf not XML": (files(x=XML.read_text().replace("</mujoco>", "")), ["mujoco", "import", "{tmp}/x.xml"],
                     ["not well-formed XML"]),
    "mjcf floor one past the last geom": (files(x=XML.read_text()), ["mujoco", "import", "{tmp}/x.xml", "--floor",
                                                                     "#999"], ["floor", "#999", "numbered #0 to"]),
    # -- 9. one line, blamed on the right input
    "unknown option": (files(s=BASE), ["simulate", "{tmp}/s.toml", "--out", "{out}", "--bogus"], ["--bogus"]),
    "missing --out": (files(s=BASE), ["identify", "{tmp}/s.toml", "--observations", "{tmp}/s.toml"], ["--out"]),
    "levels not a number": (files(s=BASE), ["convergence", "{tmp}/s.toml", "--levels", "three", "--out", "{out}"],
                            ["--levels", "three"]),
    "unknown mujoco action": (files(), ["mujoco", "fly"], ["fly"]),
    "sweep run=plan without [plan]": (files(s=BASE, w='base = "s.toml"\nrun = "plan"\n[grid]\n"friction.mu_y" = [0.1]\n'),
                                      ["sweep", "{tmp}/w.toml", "--out", "{out}"], ["[plan]"]),
}


def snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def run_case(tmp: Path, written: dict, argv: list, capsys):
    for name, text in written.items():
        suffix = {"o": ".csv" if not text.lstrip().startswith("{") else ".json", "x": ".xml", "c": ".json"}.get(name,
                                                                                                        ".toml")
        (tmp / (name + suffix)).write_text(text)
    out = tmp / "out"
    out.mkdir(exist_ok=True)
    (out / "keep.json").write_text('{"previous": "output"}')
    before = snapshot(out)
    rc = main([a.format(tmp=tmp, out=out) for a in argv])
    captured = capsys.readouterr()
    return rc, captured, before, snapshot(out)


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_command_input_is_one_line_exit_2(name, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes MUJOCO_LOG.TXT into the current folder
    written, argv, fragments = CASES[name]
    rc, captured, before, after = run_case(tmp_path, written, argv, capsys)
    lines = captured.err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT, captured.err[-500:]
    assert len(lines) == 1 and lines[0].startswith("pushplan: error: "), captured.err[-2000:]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert "Traceback" not in captured.err + captured.out
    assert after == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.")] == []


def test_the_table_covers_every_root_cause_with_several_cases():
    assert len(CASES) >= 45


def test_a_bad_run_info_in_a_recording_is_one_line(tmp_path, capsys):
    """``replay`` of a recording whose run/info is not JSON, or JSON without run_name."""
    import rerun as rr

    for i, text in enumerate(["not json {", json.dumps({"scenario": None}), json.dumps([1, 2])]):
        path = tmp_path / f"r{i}.rrd"
        rec = rr.RecordingStream(f"hostile{i}")
        rec.save(str(path))
        rec.log("run/info", rr.TextDocument(text), static=True)
        rec.flush()
        rec.disconnect()
        rc = main(["replay", str(path), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == EXIT_BAD_INPUT and len(err) == 1 and "run/info" in err[0] and path.name in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_scheduler_sending_a_plausible_length_then_garbage_is_one_line(tmp_path, capsys):
    """Past the 8-byte probe (a plausible Dask frame length), garbage: Dask's decoder
    fails with its own error types; one line, exit 2 (it was ``KeyError: 'client'``)."""
    import socket
    import struct
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(struct.pack("<Q", 100) + b"\x93\xff\x00garbage" * 20)

    threading.Thread(target=serve, daemon=True).start()
    (tmp_path / "s.toml").write_text(BASE)
    (tmp_path / "w.toml").write_text('base = "s.toml"\nworkers = 1\n[grid]\n"friction.mu_y" = [0.1]\n')
    try:
        rc = main(["sweep", str(tmp_path / "w.toml"), "--out", str(tmp_path / "out"), "--scheduler",
                   f"127.0.0.1:{server.getsockname()[1]}"])
    finally:
        server.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_BAD_INPUT and len(err) == 1 and "does not speak the Dask protocol" in err[0], err
