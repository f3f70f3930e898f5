"""Outputs that say what they mean (issue 33): the lower face's direction deviation is
``null`` in summary.json where the terminal shows ``-`` (a block that sticks), under its
own name with the old ``twist_deg`` alias; release steps and the rest step are marked in
summary.json, the terminal and the recording (the wrist force plot: tests/test_recording.py)."""

import json

from rerun.chunk import RrdReader

from pushplan.cli import main

STICKING = """
name = "sticks"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
quadrature = 2
[material]
young = 2e6
poisson = 0.45
density = 1000.0
[friction]
mu_x = 0.9
mu_y = 0.8
[[load]]
dz = -4e-4
[[load]]
dx = 1e-5
dy = 5e-6
[release]
mode = "lift"
steps = 3
[solver]
local_method = "newton"
"""


def test_a_block_that_sticks_has_null_direction_deviation_and_release_and_rest_are_marked(tmp_path, capsys):
    (tmp_path / "s.toml").write_text(STICKING)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    steps = summary["steps"]
    push = steps[1]
    # it sticks: the lower face moved by less than 1% of the upper face's 11 um
    lower, upper = (abs(complex(*push[k][:2])) for k in ("lower_centroid", "upper_centroid"))
    assert upper > 1e-5 and lower < 0.01 * upper
    assert push["lower_direction_deviation_deg"] is None and push["twist_deg"] is None
    row = next(line for line in printed.splitlines() if line.split()[:1] == ["2"])
    assert " - " in row  # the terminal's '-' is the file's null
    # release and rest
    assert [s["phase"] for s in steps] == ["command"] * 2 + ["release"] * (len(steps) - 2)
    assert len(steps) > 2 and summary["rest"]["step"] == steps[-1]["step"]
    marked = [line.split()[0] for line in printed.splitlines() if line[:4].strip().isdigit() and line[4:5] == "R"]
    assert marked == [f"{s['step']}R" for s in steps[2:]]
    # the recording marks them too
    markers, phases = [], []
    for chunk in RrdReader(out / "recording.rrd").stream().to_chunks():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/markers":
            markers += [(s, t) for s, t in zip(batch.column("step").to_pylist(),
                                               batch.column("TextLog:text").to_pylist(), strict=True)]
        if chunk.entity_path == "/run/phase":
            phases += batch.column("step").to_pylist()
    kinds = {t[0].split(":")[0]: s for s, t in markers}
    assert kinds == {"press": steps[0]["step"], "push": steps[1]["step"], "release": steps[2]["step"],
                     "rest": steps[-1]["step"]}
    assert sorted(phases) == [s["step"] for s in steps]
