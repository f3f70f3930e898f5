"""rerun recordings (pushplan.recording): read back without a viewer through
``rerun.chunk.RrdReader`` and checked against summary.json / fields.npz, the mesh
topology and the physics of the push; replay of recorded commands."""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from pushplan.cli import main
from pushplan.errors import EXIT_UNAVAILABLE
from pushplan.config.commands import commands_to_list as commands_to_json
from pushplan.outputs.recording import Recorder
from pushplan.outputs.recording_read import read_recording
from pushplan.config import load_scenario
from pushplan.run import simulate

NX, NY, NZ = 4, 4, 2
LZ = 0.010  # m, block height
PRESS = 1e-4  # m, step 1 compression
N_STEPS = 5  # 1 press + 4 pushes (the TOML below)
REPLAY_TOL = 1e-9  # m: same commands, same model -> same lower-face centroid to solver tolerance
FLOAT32_TOL = 1e-8  # m: rerun stores positions as float32 (~1e-7 relative of 0.01 m)
ENTITIES = (
    "/world/block", "/world/upper_face", "/world/lower_face", "/world/contact",
    "/plots/lower_yaw_deg", "/plots/normal_force", "/plots/tangential_force", "/plots/gripper_force",
    "/plots/newton_iterations", "/plots/contact_iterations", "/plots/lower_direction_deviation_deg",
)

SCENARIO = """
name = "{name}"
[block]
size = [0.020, 0.020, 0.010]
elements = [4, 4, 2]
quadrature = 2
[material]
young = 210.0e9
poisson = 0.3
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
[[load]]
dz = -0.1e-3
[[load]]
distance = 0.32e-3
direction_deg = 45.0
repeat = 4
[solver]
local_method = "newton"
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Scenario files and one simulate run (anisotropic case-3 friction) via the CLI."""
    root = tmp_path_factory.mktemp("rec")
    aniso = root / "aniso.toml"
    aniso.write_text(SCENARIO.format(name="aniso", mu_x=0.3, mu_y=0.05))
    iso = root / "iso.toml"
    iso.write_text(SCENARIO.format(name="iso", mu_x=0.2, mu_y=0.2))
    run = root / "run"
    assert main(["simulate", str(aniso), "--out", str(run), "--quiet"]) == 0
    return {"root": root, "aniso": aniso, "iso": iso, "run": run}


def chunks(path, entity):
    """Record batches of one entity (temporal and static)."""
    return [c.to_record_batch() for c in RrdReader(path).stream().to_chunks() if c.entity_path == entity]


def column(path, entity, name):
    """(steps, values) of a temporal column, sorted by step."""
    rows = []
    for b in chunks(path, entity):
        if "step" in b.schema.names and name in b.schema.names:
            rows += zip(b.column("step").to_pylist(), b.column(name).to_pylist(), strict=True)
    rows.sort(key=lambda r: r[0])
    return [r[0] for r in rows], [r[1] for r in rows]


def summary_steps(folder):
    return json.loads((Path(folder) / "summary.json").read_text())["steps"]


def test_entity_paths_and_step_count(files):
    rrd = files["run"] / "recording.rrd"
    paths = {c.entity_path for c in RrdReader(rrd).stream().to_chunks()}
    assert set(ENTITIES) <= paths
    for entity in ENTITIES[4:-1]:  # the direction deviation has no point while the lower face sticks
        steps, _ = column(rrd, entity, "Scalars:scalars")
        assert steps == list(range(1, N_STEPS + 1)), entity
    assert not list(files["run"].glob(".recording.rrd.*"))  # temporary file renamed


def test_direction_deviation_and_forces_equal_summary(files):
    rrd = files["run"] / "recording.rrd"
    steps = summary_steps(files["run"])
    at, twist = column(rrd, "/plots/lower_direction_deviation_deg", "Scalars:scalars")
    defined = [(s["step"], s["lower_direction_deviation_deg"]) for s in steps
               if s["lower_direction_deviation_deg"] is not None]
    assert list(zip(at, [t[0] for t in twist], strict=True)) == defined
    assert steps[0]["lower_direction_deviation_deg"] is None and steps[0]["twist_deg"] is None  # the press
    assert all(s["twist_deg"] == s["lower_direction_deviation_deg"] for s in steps)  # the alias
    _, normal = column(rrd, "/plots/normal_force", "Scalars:scalars")
    assert [n[0] for n in normal] == [s["normal_force"] for s in steps]
    _, grip = column(rrd, "/plots/gripper_force", "Scalars:scalars")  # the wrist force
    assert [list(g) for g in grip] == [s["upper_force"] for s in steps]
    assert all(s["phase"] == "command" for s in steps)
    # physics: elliptic friction with mu_x != mu_y twists the 45-degree push
    assert abs(twist[-1][0]) > 1.0


def test_mesh_vertices_and_deformed_positions(files):
    rrd = files["run"] / "recording.rrd"
    n_surface = (NX + 1) * (NY + 1) * (NZ + 1) - (NX - 1) * (NY - 1) * (NZ - 1)
    (static,) = [b for b in chunks(rrd, "/world/block") if "Mesh3D:triangle_indices" in b.schema.names]
    triangles = np.array(static.column("Mesh3D:triangle_indices").to_pylist()[0])
    assert len(triangles) == 2 * 2 * (NX * NY + NY * NZ + NZ * NX)  # two per boundary quad
    assert set(np.unique(triangles)) == set(range(n_surface))
    steps, positions = column(rrd, "/world/block", "Mesh3D:vertex_positions")
    assert steps == list(range(N_STEPS + 1))  # step 0 is the undeformed block
    final = np.array(positions[-1])
    assert final.shape == (n_surface, 3)
    # the upper face follows the prescribed press; the lower face stays on the plane
    assert final[:, 2].max() == pytest.approx(LZ - PRESS, abs=FLOAT32_TOL)
    assert final[:, 2].min() > -FLOAT32_TOL
    _, colours = column(rrd, "/world/block", "Mesh3D:vertex_colors")
    assert len(colours[-1]) == n_surface


def test_lower_face_trajectory_and_commands(files):
    rrd = files["run"] / "recording.rrd"
    steps = summary_steps(files["run"])
    _, strips = column(rrd, "/world/lower_face", "LineStrips3D:strips")
    last = np.array(strips[-1][0])
    assert last.shape == (N_STEPS + 1, 3)
    lower = np.array([s["lower_centroid"] for s in steps])
    np.testing.assert_allclose(last[1:], lower, atol=FLOAT32_TOL)
    rec = read_recording(rrd)
    scenario = json.loads((files["run"] / "summary.json").read_text())["scenario"]
    assert [c["dz"] for c in commands_to_json(rec.commands)] == [c["dz"] for c in scenario["load"]]
    np.testing.assert_array_equal(rec.lower_centroid, lower)


def test_replay_recording_reproduces(files, capsys):
    out = files["root"] / "replay_same"
    assert main(["replay", str(files["run"] / "recording.rrd"), "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    dev = float(re.search(r"max lower-face deviation from aniso: (\S+) m", printed).group(1))
    assert dev <= REPLAY_TOL
    assert f"{N_STEPS} steps compared" in printed  # not "step 1 of 5 compared" (issue 22)
    a = np.array([s["lower_centroid"] for s in summary_steps(files["run"])])
    b = np.array([s["lower_centroid"] for s in summary_steps(out)])
    assert np.abs(a - b).max() <= REPLAY_TOL
    assert read_recording(out / "recording.rrd").run_name == "aniso-replay"


def test_replay_plan_with_other_friction(files, capsys):
    rrd = files["run"] / "recording.rrd"
    plan = files["run"] / "plan.json"  # next to the run's recording.rrd, the reference
    plan.write_text(json.dumps({"commands": commands_to_json(read_recording(rrd).commands)}))
    out = files["root"] / "replay_iso"
    assert main(["replay", str(plan), "--scenario", str(files["iso"]), "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    dev = float(re.search(r"max lower-face deviation from aniso: (\S+) m", printed).group(1))
    a = np.array([s["lower_centroid"] for s in summary_steps(files["run"])])
    iso_steps = summary_steps(out)
    b = np.array([s["lower_centroid"] for s in iso_steps])
    assert dev == pytest.approx(np.linalg.norm(a - b, axis=1).max(), rel=1e-6)
    assert dev > 1e-6  # micrometres apart, not solver noise
    # physics: isotropic friction and a symmetric block: the lower face follows the push
    assert max(abs(s["lower_direction_deviation_deg"]) for s in iso_steps[1:]) < 0.01
    assert json.loads((out / "replay.json").read_text())["max_deviation_m"] == pytest.approx(dev, rel=1e-6)


def _data(path):
    """All data columns per entity, without row ids and wall-clock columns."""
    out = {}
    for c in RrdReader(path).stream().to_chunks():
        b = c.to_record_batch()
        cols = {n: b.column(n).to_pylist() for n in b.schema.names if n not in ("rerun.controls.RowId", "log_time")}
        out.setdefault((c.entity_path, c.is_static), []).append(json.dumps(cols, sort_keys=True))
    return {k: sorted(v) for k, v in out.items()}


def test_recordings_are_deterministic(files, tmp_path, monkeypatch):
    monkeypatch.delenv("RERUN_LOG_TIME", raising=False)
    scenario = load_scenario(files["aniso"])
    paths = []
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        simulate(scenario, tmp_path / name)
        paths.append(tmp_path / name / "recording.rrd")
    ids = [RrdReader(p).recordings()[0].recording_id for p in paths]
    assert ids[0] == ids[1]
    a, b = _data(paths[0]), _data(paths[1])
    assert a == b
    assert all("log_time" not in c.timeline_names for c in RrdReader(paths[0]).stream().to_chunks())
    exe = shutil.which("rerun") or shutil.which("rerun", path=str(Path(sys.executable).parent))
    if exe:  # the rerun CLI ships with rerun-sdk; compare with it where it exists
        res = subprocess.run([exe, "rrd", "compare", "--unordered", *map(str, paths)],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr[-2000:]
    # another friction gives another recording
    other = tmp_path / "iso"
    other.mkdir()
    simulate(load_scenario(files["iso"]), other)
    assert RrdReader(other / "recording.rrd").recordings()[0].recording_id != ids[0]


def test_log_time_opt_in(files, tmp_path, monkeypatch):
    mesh = load_scenario(files["aniso"]).model().mesh
    monkeypatch.setenv("RERUN_LOG_TIME", "1")
    with Recorder(tmp_path / "t.rrd", "t", mesh):
        pass
    assert any("log_time" in c.timeline_names for c in RrdReader(tmp_path / "t.rrd").stream().to_chunks())


def test_log_plan(files, tmp_path):
    mesh = load_scenario(files["aniso"]).model().mesh
    predicted = np.array([[0.0, 0.0, 0.0], [1e-3, 2e-4, 0.01], [2e-3, 5e-4, 0.02]])
    cost = [5.0, 1.0, 0.25, 0.125]
    with Recorder(tmp_path / "p.rrd", "plan", mesh) as rec:
        with pytest.raises(ValueError, match="verified"):
            rec.log_plan(verified=np.zeros((3, 4)))
        rec.log_plan(target=(2e-3, 5e-4, 0.02), predicted=predicted, verified=predicted[:, :2],
                     naive=predicted * 0.5, cost=cost)
    path = tmp_path / "p.rrd"
    (b,) = chunks(path, "/plan/predicted")
    strip = np.array(b.column("LineStrips3D:strips").to_pylist()[0][0])
    np.testing.assert_allclose(strip[:, :2], predicted[:, :2], rtol=1e-6)
    np.testing.assert_allclose(strip[:, 2], 0.0)
    vectors = np.array(b.column("Arrows3D:vectors").to_pylist()[0])
    np.testing.assert_allclose(np.arctan2(vectors[:, 1], vectors[:, 0]), predicted[:, 2], atol=1e-6)
    (t,) = chunks(path, "/plan/target")
    np.testing.assert_allclose(t.column("Boxes3D:half_sizes").to_pylist()[0][0], [0.01, 0.01, 0.0])
    rows = [(i, v) for b in chunks(path, "/plots/planner_cost")
            for i, v in zip(b.column("planner_iteration").to_pylist(), b.column("Scalars:scalars").to_pylist(), strict=True)]
    assert sorted(rows) == [(i, [c]) for i, c in enumerate(cost)]
    assert {"/plan/verified", "/plan/naive"} <= {c.entity_path for c in RrdReader(path).stream().to_chunks()}


def test_no_recording_and_bad_input(files, tmp_path, monkeypatch, capsys):
    out = tmp_path / "norec"
    assert main(["simulate", str(files["aniso"]), "--out", str(out), "--quiet", "--no-recording"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["fields.npz", "summary.json"]
    mesh = load_scenario(files["aniso"]).model().mesh
    with pytest.raises(ValueError, match="field"):
        Recorder(tmp_path / "x.rrd", "x", mesh, field="temperature")
    assert main(["replay", str(files["aniso"]), "--out", str(tmp_path / "r")]) == 2
    assert main(["replay", str(tmp_path / "missing.rrd"), "--out", str(tmp_path / "r")]) == 2
    assert main(["view", str(tmp_path / "missing.rrd")]) == 2
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    capsys.readouterr()
    assert main(["view", str(files["run"] / "recording.rrd")]) == EXIT_UNAVAILABLE  # no viewer can open
    assert "rerun " in capsys.readouterr().err


def test_vertex_normals_point_out_of_the_block(files):
    """Normals of the undeformed box point outward, and inside a face they are the
    face's normal (geometry of a box, independent of the code)."""
    rrd = files["run"] / "recording.rrd"
    _, positions = column(rrd, "/world/block", "Mesh3D:vertex_positions")
    _, normals = column(rrd, "/world/block", "Mesh3D:vertex_normals")
    x, n = np.array(positions[0]), np.array(normals[0])
    centre = np.array([0.0, 0.0, LZ / 2])
    assert np.all(np.sum((x - centre) * n, axis=1) > 0)
    half = np.array([0.01, 0.01, LZ / 2])
    on = np.isclose(np.abs(x - centre), half, atol=1e-7)  # which bounding planes a vertex lies on
    face = on.sum(axis=1) == 1
    np.testing.assert_allclose(np.abs(n[face]), on[face].astype(float), atol=1e-6)


def test_colour_scale_is_fixed_over_the_run_and_fields_are_data(files):
    """One colour range and one arrow scale for the whole run (logged per step as data),
    covering every step's values; the lower-face fields are in the recording as numbers
    equal to fields.npz (issue 22)."""
    rrd = files["run"] / "recording.rrd"
    steps, high = column(rrd, "/run/colour_scale", "high")
    assert steps == list(range(1, N_STEPS + 1))
    assert len({h[0] for h in high}) == 1  # constant over the run
    with np.load(files["run"] / "fields.npz") as f:
        slip = f["slip"]
    assert high[0][0] == pytest.approx(slip.max(), rel=1e-12)  # covers every step, and no more
    data_steps, values = column(rrd, "/world/contact", "slip")
    assert data_steps == steps
    np.testing.assert_allclose(np.array(values, float), slip, rtol=1e-12, atol=0)
    _, scale = column(rrd, "/run/colour_scale", "arrow_m_per_n")
    assert len({s[0] for s in scale}) == 1
    # colours on the run's scale: at the first push step, when slip is still small, no
    # lower-face vertex is yellow (a per-step scale would make its largest value yellow)
    colour_steps, colours = column(rrd, "/world/block", "Mesh3D:vertex_colors")
    assert colour_steps[-N_STEPS:] == steps
    assert slip[1].max() < 0.5 * slip.max()
    yellow = 0xFDE725FF  # viridis at 1 (rgba)
    assert yellow not in colours[-N_STEPS + 1] and yellow in colours[-1]


def test_scene_floor_friction_ellipse_and_gripper(files):
    rrd = files["run"] / "recording.rrd"
    (friction,) = chunks(rrd, "/world/friction")
    ellipse = np.array(friction.column("LineStrips3D:strips").to_pylist()[0][0])
    semi = np.abs(ellipse[:, :2]).max(axis=0)
    assert semi[0] / semi[1] == pytest.approx(0.3 / 0.05, rel=1e-3)  # mu_x / mu_y of the aniso scenario
    assert chunks(rrd, "/world/floor")
    steps, centres = column(rrd, "/world/gripper", "Boxes3D:centers")
    assert steps == list(range(N_STEPS + 1))
    lower = np.array([s["upper_centroid"] for s in summary_steps(files["run"])])
    np.testing.assert_allclose(np.array(centres)[1:, 0, :2], lower[:, :2], atol=FLOAT32_TOL)


def test_plan_overlays_follow_the_step_timeline(files, tmp_path):
    mesh = load_scenario(files["aniso"]).model().mesh
    verified = np.array([[0.0, 0.0, 0.0], [1e-3, 2e-4, 0.01], [2e-3, 5e-4, 0.02]])
    with Recorder(tmp_path / "p.rrd", "plan", mesh) as rec:
        rec.log_plan(target=(2e-3, 5e-4, 0.02), verified=verified, naive=verified * 0.5, first_step=1)
    for entity in ("/plan/verified", "/plan/naive", "/plan/target"):
        steps, _ = column(tmp_path / "p.rrd", entity, "Boxes3D:centers" if entity.endswith("target")
                          else "LineStrips3D:strips")
        assert steps == [1, 2, 3], entity
    _, strips = column(tmp_path / "p.rrd", "/plan/verified", "LineStrips3D:strips")
    assert [len(s[0]) for s in strips] == [1, 2, 3]  # the path so far at each step


def test_every_output_file_follows_the_umask(files, tmp_path):
    old = os.umask(0o022)
    try:
        out = tmp_path / "u"
        assert main(["simulate", str(files["aniso"]), "--out", str(out), "--quiet"]) == 0
    finally:
        os.umask(old)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in out.iterdir()}
    assert modes == {"summary.json": 0o644, "fields.npz": 0o644, "recording.rrd": 0o644}
