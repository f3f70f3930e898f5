"""What a run tells (issue 43 items 4 and 6): a frictional pad's slip over the upper face
per step and when it let go, in summary.json, the terminal and the recording, with a
warning when it slid over most of the commanded travel; the recording's labelled phases
(press, push, release, rest) read back with rerun-sdk; a plan to a rest target records
its verified release and rest pose."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pushplan.cli import main

PAD_SLIDES = """
name = "pad_slides"
[block]
size = [0.04, 0.03, 0.02]
elements = [2, 2, 1]
quadrature = 2
[material]
young = 2e6
poisson = 0.3
density = 1000.0
[friction]
mu_x = 0.5
mu_y = 0.25
[gripper]
friction = {pad}
[[load]]
dz = -4e-4
[[load]]
dx = 3e-4
repeat = 6
[release]
mode = "lift"
steps = 4
"""


def _rows(path, entity: str, column: str) -> list:
    """(step, value) rows of one component column of a recording, in step order."""
    from rerun.chunk import RrdReader

    found = []
    for chunk in RrdReader(path).stream().filter(content=entity).to_chunks():
        batch = chunk.to_record_batch()
        found += zip(batch.column("step").to_pylist(), batch.column(column).to_pylist(), strict=True)
    return sorted(found, key=lambda r: r[0])


@pytest.fixture(scope="module")
def pad_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pad_slides")
    (tmp / "s.toml").write_text(PAD_SLIDES.format(pad=0.2))
    return tmp


def test_a_sliding_pad_reports_its_slip_and_warns(pad_run, capsys):
    """The issue's case: a pad of 0.2 on a 0.5 / 0.25 floor pushed 1.8 mm slides about
    1.5 mm over the upper face (the upper face moves 0.23 mm); measured 1.573 mm, which
    is the commanded travel less the upper face's (the pad's slip is their difference)."""
    out = pad_run / "out"
    assert main(["simulate", str(pad_run / "s.toml"), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    doc = json.loads((out / "summary.json").read_text())
    loaded = [s for s in doc["steps"] if s["phase"] == "command"]
    last = loaded[-1]
    commanded = 6 * 3e-4
    assert last["pad_slip"] == pytest.approx(commanded - math.hypot(*last["upper_centroid"][:2]), rel=1e-9)
    assert 1.4e-3 < last["pad_slip"] < 1.7e-3
    assert all(b["pad_slip"] >= a["pad_slip"] - 1e-12 for a, b in zip(loaded[1:-1], loaded[2:], strict=True))
    assert doc["rest"]["pad_slip"] >= last["pad_slip"]  # it slides on as the block springs back under it
    assert len(doc["warnings"]) == 1 and "the pad slid 1.57 mm" in doc["warnings"][0]
    assert "pushplan: warning: the pad slid 1.57 mm" in captured.err
    assert "pad slip" in captured.out and "when it let go" in captured.out
    # the recording: the slip per step, the labelled phases, the rest and the warning
    rrd = out / "recording.rrd"
    slip = [v[0] for _, v in _rows(rrd, "/plots/pad_slip", "Scalars:scalars")]
    np.testing.assert_allclose(slip, [s["pad_slip"] for s in doc["steps"]], rtol=1e-12)
    markers = [(k, text[0]) for k, text in _rows(rrd, "/markers", "TextLog:text")]
    starts = [text.split(":")[0] for _, text in markers]
    assert starts == ["press", "push", "release", "rest", "the pad slid 1.57 mm over the upper face of the 1.8 mm "
                      "commanded in the plane (the upper face moved 0.227 mm)"]
    assert markers[0][0] == 1 and markers[1][0] == 2 and markers[2][0] == 8 and markers[3][0] == doc["rest"]["step"]
    labels = [label[0] for _, label in _rows(rrd, "/run/phase", "label")]
    assert labels == ["press"] + ["push"] * 6 + ["release"] * (len(doc["steps"]) - 7)


def test_a_pad_that_drags_the_block_does_not_warn(tmp_path, capsys):
    """A pad of the floor's friction times 3 drags the block: its slip is a small part of
    the command and nothing warns; a bonded gripper has no pad slip."""
    text = PAD_SLIDES.format(pad=1.5).replace("[release]\nmode = \"lift\"\nsteps = 4\n", "")
    (tmp_path / "s.toml").write_text(text)
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o"), "--quiet",
                 "--no-recording"]) == 0
    doc = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert "warnings" not in doc and "warning" not in capsys.readouterr().err
    assert doc["steps"][-1]["pad_slip"] < 0.5 * 1.8e-3
    (tmp_path / "b.toml").write_text(text.replace("[gripper]\nfriction = 1.5\n", ""))
    assert main(["simulate", str(tmp_path / "b.toml"), "--out", str(tmp_path / "b"), "--quiet",
                 "--no-recording"]) == 0
    assert all(s["pad_slip"] is None for s in json.loads((tmp_path / "b" / "summary.json").read_text())["steps"])


PLAN_TO_REST = """
name = "lift_plan"
[block]
size = [0.04, 0.03, 0.02]
elements = [3, 2, 2]
quadrature = 2
[material]
young = 2e6
poisson = 0.45
density = 0.0
[friction]
mu_x = 0.6
mu_y = 0.2
angle_deg = 20.0
[[load]]
dz = -4e-4
[release]
mode = "lift"
steps = 4
[plan]
x = 3e-3
y = 1e-3
yaw_deg = 5.0
steps = 5
max_step = 1.2e-3
max_dtheta_deg = 2.0
tolerance = 3e-5
planning_elements = [3, 2, 2]
planning_quadrature = 2
"""


def test_a_plan_to_rest_records_its_verified_release_and_rest_pose(tmp_path):
    """The issue: a plan to a rest target wrote a recording that ended at the loaded pose
    next to the target box.  Now its verified release steps follow the pushes (labelled
    ``release``) and ``plan/rest`` ends at plan.json's verified rest pose, with a marker."""
    (tmp_path / "p.toml").write_text(PLAN_TO_REST)
    out = tmp_path / "plan"
    assert main(["plan", str(tmp_path / "p.toml"), "--out", str(out), "--quiet", "--no-baseline"]) == 0
    doc = json.loads((out / "plan.json").read_text())
    rest = np.array(doc["final_poses"]["rest"]["pose"][:2])  # m (yaw in deg)
    rrd = out / "recording.rrd"
    labels = [label[0] for _, label in _rows(rrd, "/run/phase", "label")]
    assert labels[:6] == ["press"] + ["push"] * 5 and len(labels) > 6 and set(labels[6:]) == {"release"}
    markers = [text[0] for _, text in _rows(rrd, "/markers", "TextLog:text")]
    assert any(m.startswith("rest: the verified release") for m in markers), markers
    path = [p for _, p in _rows(rrd, "/plan/rest", "LineStrips3D:strips")]
    assert path, "no plan/rest"
    start, end = (np.asarray(p, float) for p in np.asarray(path[-1][0]))
    loaded = np.array(doc["final_poses"]["loaded"]["pose"][:2])
    np.testing.assert_allclose(end[:2], rest, atol=1e-8)  # float32 in the recording
    np.testing.assert_allclose(start[:2], loaded, atol=1e-8)
    assert np.linalg.norm(rest - loaded) > 1e-4  # the springback the viewer now shows
