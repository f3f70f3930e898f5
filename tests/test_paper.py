"""Acceptance tests of issue 4: the claims of sect. 9.1 / 9.2 of Feng, Hjiaj, de Saxce,
Mroz (2006), measured on the fields that ``pushplan paper`` writes for a CI-coarse mesh.

The three cases run once (module fixture) through the CLI.  Every measure below is
computed here from ``fields.npz`` (raw nodal fields), not taken from the command's
own claim verdicts; ``report.json`` is then checked against these measures.

Where the paper's wording does not hold literally, the test asserts what does hold
(see the claim 1 and claim 2 docstrings) and the numbers are in the report.
"""

import contextlib
import io
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pushplan import cli
from pushplan.cli import paper as paper_cli
from pushplan.studies import paper_figures

ELEMENTS = (10, 10, 4)  # even nx, ny: node lines on the axes and diagonals through the centre
QUADRATURE = 2
CASES = ("paper_case1", "paper_case2", "paper_case3")
PUSH = np.array([1.0, 1.0]) / math.sqrt(2.0)  # scenarios: 4 pushes at 45 deg
LX = LY = 0.020
E, NU, LZ, DZ = 210e9, 0.3, 0.010, 0.1e-3

SYMMETRY_RTOL = 1e-6  # mirror-symmetric problems: equal to solver tolerance (1e-10) plus margin
MONOTONE_TOL = 1e-3  # slip may drop by 0.1 % of its max along a line from the centre (round-off, no physics)
ANISO_MIN_RATIO = 1.5  # case 2 friction ellipse has axis ratio 2; slip ratios must clearly exceed 1
CLOSE_RTOL = 0.05  # "differ little" / "no significant difference": within 5 %
EDGE_PRESSURE_MIN_RATIO = 1.1  # edge pressure peak over centre pressure (measured 1.24-1.30)
FRONT_BACK_MIN_RATIO = 1.2  # front half carries clearly more than the back half (measured 1.3-1.4)
TWIST_ISO_DEG = 1e-6  # isotropic case: symmetric about the push direction, zero to solver tolerance
TWIST_ANISO_MIN_DEG = 1.0  # anisotropic: well above solver noise (measured 2.3 and 3.2 deg)
PNG_MIN_SIZE = (400, 1000)  # rows, columns at 110 dpi
PNG_MIN_INK = 0.05  # fraction of non-white pixels
PNG_MIN_COLOURS = 50

pytestmark = pytest.mark.xdist_group("paper")  # one worker runs the module fixture (with --dist loadgroup)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    docs = out / "docs_figures"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = cli.main([
            "paper", "--out", str(out), "--elements", *map(str, ELEMENTS), "--quadrature", str(QUADRATURE),
            "--local-method", "newton", "--docs", str(docs),
        ])
    fields = {}
    for name in CASES:
        with np.load(out / name / "fields.npz") as f:
            fields[name] = {k: f[k] for k in f.files}
    return SimpleNamespace(out=out, docs=docs, code=code, fields=fields, stdout=printed.getvalue(),
                           report=json.loads((out / "report.json").read_text()))


def grid(f, key, step):
    """Lower-face field of one step on its (ny+1, nx+1) grid, with the reference x, y grids."""
    nx, ny, _ = ELEMENTS
    X = f["nodes"][f["lower"]]
    shape = (ny + 1, nx + 1)
    if key == "r_n":
        v = f["reaction_local"][step][:, 0]
    else:
        v = f[key][step]
    return v.reshape(shape), X[:, 0].reshape(shape), X[:, 1].reshape(shape)


def centre_lines(g):
    """The 8 node lines from the centre node to the edge: half-axes and half-diagonals."""
    c = g.shape[0] // 2
    idx = np.arange(c + 1)
    return [g[c, c:], g[c, c::-1], g[c:, c], g[c::-1, c],
            g[c + idx, c + idx], g[c - idx, c - idx], g[c + idx, c - idx], g[c - idx, c + idx]]


def crossing(profile, h, level):
    """Distance from the centre where a node-line profile first reaches ``level`` (linear)."""
    k = int(np.argmax(profile >= level))
    assert profile[k] >= level
    return h * (k - 1 + (level - profile[k - 1]) / (profile[k] - profile[k - 1]))


def test_command_runs_all_cases(run):
    assert run.code == 0
    assert run.report["status"] == "completed"
    for case in run.report["cases"]:
        assert case["status"] == "completed" and len(case["steps"]) == 5
    assert run.report["run"]["elements"] == list(ELEMENTS)


def test_claims_are_printed_as_findings_not_errors(run):
    """A claim the run does not reproduce is a finding of the study (discussed in
    docs/paper-reproduction.md), printed as such: no capitals, no 'NOT'."""
    lines = [line for line in run.stdout.splitlines() if line.startswith("claim ")]
    assert len(lines) == len(run.report["claims"])
    for line, (key, claim) in zip(lines, run.report["claims"].items(), strict=True):
        expected = "reproduced" if claim["holds"] else "partly reproduced; finding"
        assert line.startswith(f"claim {key}: {expected}"), line
    assert "NOT" not in run.stdout


def test_claim1_stick_zone_at_centre_and_slip_grows_outward(run):
    """After compression: the centre sticks, no periphery node sticks, the stick zone is
    centred, and slip never decreases along the 8 node lines from the centre."""
    for name in CASES:
        f = run.fields[name]
        slip, x, y = grid(f, "slip", 0)
        status = f["node_status"][0].reshape(slip.shape)
        c = slip.shape[0] // 2
        assert status[c, c] == 0, name
        stick = status == 0
        edge = np.zeros_like(stick)
        edge[[0, -1], :] = edge[:, [0, -1]] = True
        assert not (stick & edge).any(), name
        assert abs(x[stick].mean()) < 1e-12 and abs(y[stick].mean()) < 1e-12, name
        for line in centre_lines(slip):
            assert np.all(np.diff(line) >= -MONOTONE_TOL * slip.max()), name


def test_claim1_slip_shape_follows_friction_ellipse(run):
    """Slip is larger along y (low friction): slip(0, +-ly/2) / slip(+-lx/2, 0) is 1 for the
    isotropic case and grows with mu_x / mu_y.  The iso-lines are therefore *flat* in y,
    i.e. elongated along x like the friction ellipse (semi-axes mu_x, mu_y), as the paper
    says ("flat ellipses ... exactly like the friction criterion"); the issue's
    "elongated along y" does not hold for the iso-line shape."""
    h = LX / ELEMENTS[0]
    ratio, aspect = [], []
    for name in CASES:
        slip, _, _ = grid(run.fields[name], "slip", 0)
        lines = centre_lines(slip)
        s_x = 0.5 * (lines[0][-1] + lines[1][-1])
        s_y = 0.5 * (lines[2][-1] + lines[3][-1])
        level = 0.5 * min(s_x, s_y)
        r_x = np.mean([crossing(p, h, level) for p in lines[:2]])
        r_y = np.mean([crossing(p, h, level) for p in lines[2:4]])
        ratio.append(s_y / s_x)
        aspect.append(r_x / r_y)
    assert ratio[0] == pytest.approx(1.0, rel=SYMMETRY_RTOL)
    assert aspect[0] == pytest.approx(1.0, rel=SYMMETRY_RTOL)
    assert ANISO_MIN_RATIO < ratio[1] < ratio[2]
    assert ANISO_MIN_RATIO < aspect[1] < aspect[2]
    claim = run.report["claims"]["1_compression_slip"]
    assert claim["holds"] and all(c["holds"] for c in claim["checks"])
    for k in range(3):  # the report's numbers are the ones measured here
        assert claim["cases"][k]["y_over_x"] == pytest.approx(ratio[k], rel=1e-6)
        assert claim["cases"][k]["iso_aspect_x_over_y"] == pytest.approx(aspect[k], rel=1e-3)


def test_claim2_normal_reaction_after_compression(run):
    """Nodal r_n: near its max at the centre (within 5 %), min on the periphery, max
    differing little across cases.  The paper's "largest r_n around the centre" holds
    on this coarse mesh but not on the paper's 20 x 20 mesh, where the global max sits
    one element in from the edge midpoints (3-4 % above the centre value), so only the
    weaker statement is asserted.  The pressure (r_n / tributary area) tells the opposite story to r_n:
    it peaks on the periphery, well above the centre (the edge effect hidden in r_n by
    the 1/4 and 1/2 tributary areas of corner and edge nodes).  The total force lies
    between the uniaxial-stress and the laterally-confined elastic bounds."""
    rn_max = []
    for name in CASES:
        f = run.fields[name]
        rn, x, y = grid(f, "r_n", 0)
        p, _, _ = grid(f, "pressure", 0)
        c = rn.shape[0] // 2
        assert rn[c, c] > (1 - CLOSE_RTOL) * rn.max(), name
        pos = np.maximum(np.abs(x) / (LX / 2), np.abs(y) / (LY / 2))
        assert pos.flat[rn.argmin()] == pytest.approx(1.0), name
        assert pos.flat[p.argmax()] == pytest.approx(1.0), name
        assert p.max() > EDGE_PRESSURE_MIN_RATIO * p[c, c], name
        rn_max.append(rn.max())
        uniaxial = E * LX * LY * DZ / LZ
        confined = uniaxial * (1 - NU) / ((1 + NU) * (1 - 2 * NU))
        assert uniaxial < rn.sum() < confined, name
    spread = np.ptp(rn_max) / np.mean(rn_max)
    assert spread < CLOSE_RTOL
    claim = run.report["claims"]["2_compression_normal_reaction"]
    assert claim["r_n"]["max_spread"] == pytest.approx(spread, rel=1e-9)
    centre_over_max = []
    for name in CASES:
        rn = grid(run.fields[name], "r_n", 0)[0]
        centre_over_max.append(rn[rn.shape[0] // 2, rn.shape[1] // 2] / rn.max())
    assert claim["r_n"]["centre_over_max"] == pytest.approx(centre_over_max)


def test_claim3_slip_after_sliding(run):
    """Max slip at the front corner (+lx/2, +ly/2); case 1 and case 2 max slips close;
    case 3 moves its lower face furthest in y."""
    max_slip, mean_y = [], []
    for name in CASES:
        f = run.fields[name]
        slip, x, y = grid(f, "slip", -1)
        k = slip.argmax()
        assert (x.flat[k], y.flat[k]) == pytest.approx((LX / 2, LY / 2)), name
        max_slip.append(slip.max())
        mean_y.append(f["displacement"][-1][f["lower"], 1].mean())
        step = next(c for c in run.report["cases"] if c["name"] == name)["steps"][-1]
        assert step["max_slip"] == pytest.approx(slip.max(), rel=1e-12)
        assert step["max_slip_at"] == pytest.approx([x.flat[k], y.flat[k]])
    assert abs(max_slip[0] - max_slip[1]) / max_slip[0] < CLOSE_RTOL
    assert mean_y[2] > mean_y[1] > mean_y[0]


def test_claim4_normal_reaction_after_sliding(run):
    """r_n and pressure: max ahead of the centre, min behind it, front half loaded more
    than the back half.  The minima are close across cases (spread well under 5 % of the
    max r_n), but the maxima are not "very close": they grow with the total friction
    force (case 1 < 2 < 3, spread ~9 % here, ~12 % on the paper mesh), which is what is
    asserted instead."""
    rn_max, rn_min, friction = [], [], []
    for name in CASES:
        f = run.fields[name]
        for key in ("r_n", "pressure"):
            v, x, y = grid(f, key, -1)
            s = x * PUSH[0] + y * PUSH[1]
            assert s.flat[v.argmax()] > 0 > s.flat[v.argmin()], (name, key)
            assert v[s > 0].mean() > FRONT_BACK_MIN_RATIO * v[s < 0].mean(), (name, key)
        rn, _, _ = grid(f, "r_n", -1)
        rn_max.append(rn.max())
        rn_min.append(rn.min())
        friction.append(np.hypot(*f["reaction_world"][-1][:, :2].sum(axis=0)))
    assert np.ptp(rn_min) / np.mean(rn_max) < CLOSE_RTOL
    assert np.all(np.diff(friction) > 0) and np.all(np.diff(rn_max) > 0)
    assert run.report["claims"]["4_sliding_normal_reaction"]["r_n"]["max_spread"] == pytest.approx(
        np.ptp(rn_max) / np.mean(rn_max), rel=1e-9)


def test_claim5_twist(run):
    """Lower-face mean displacement: along the 45 deg push for the isotropic case; turned
    toward y (the low-friction axis) for the anisotropic cases, more for case 3."""
    deviation = []
    for name in CASES:
        f = run.fields[name]
        u = f["displacement"][-1][f["lower"], :2]
        w = f["lower_area"] / f["lower_area"].sum()
        lo = w @ u
        deviation.append(math.degrees(math.atan2(lo[1], lo[0])) - 45.0)
        step = next(c for c in run.report["cases"] if c["name"] == name)["steps"][-1]
        assert step["lower_direction_deg"] - 45.0 == pytest.approx(deviation[-1], abs=1e-6)
    assert abs(deviation[0]) < TWIST_ISO_DEG
    assert TWIST_ANISO_MIN_DEG < deviation[1] < deviation[2]
    twist = [c["steps"][-1]["twist_deg"] for c in run.report["cases"]]
    assert abs(twist[0]) < TWIST_ISO_DEG and TWIST_ANISO_MIN_DEG < abs(twist[1]) < abs(twist[2])


def test_claim6_figures_are_generated_and_not_blank(run):
    from matplotlib.image import imread

    names = sorted(p.name for p in (run.out / "figures").glob("*.png"))
    expected = sorted([f"{n}.png" for n in paper_figures.FIGURES] + ["fig10_deformed.png"])
    assert names == expected
    for name in names:
        img = imread(run.out / "figures" / name)[..., :3]
        assert img.shape[0] >= PNG_MIN_SIZE[0] and img.shape[1] >= PNG_MIN_SIZE[1], name
        assert (img.min(axis=-1) < 0.95).mean() > PNG_MIN_INK, name
        rgb = (img * 255).astype(np.int32)
        assert np.unique(rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2]).size > PNG_MIN_COLOURS, name
        assert (run.docs / name).read_bytes() == (run.out / "figures" / name).read_bytes()
    # The three panels of a contour figure show different fields (not one image copied).
    img = imread(run.out / "figures" / "fig06_slip_compression.png")[..., :3]
    w = img.shape[1] // 3
    assert not np.allclose(img[:, :w], img[:, w:2 * w])


def test_vtu_holds_the_deformed_block_and_nodal_fields(run):
    import meshio

    f = run.fields["paper_case3"]
    folder = run.out / "paper_case3" / "vtu"
    mesh = meshio.read(folder / "step_05.vtu")
    assert np.allclose(mesh.points, f["nodes"] + f["displacement"][-1], rtol=0, atol=1e-15)
    assert mesh.cells_dict["hexahedron"].shape == (np.prod(ELEMENTS), 8)
    assert np.array_equal(mesh.point_data["slip"][f["lower"]], f["slip"][-1])
    assert np.array_equal(mesh.point_data["r_n"][f["lower"]], f["reaction_local"][-1][:, 0])
    others = np.setdiff1d(np.arange(len(mesh.points)), f["lower"])
    assert np.all(mesh.point_data["contact_status"][others] == -1)
    pvd = (folder / "block.pvd").read_text()
    assert all(f'file="step_{k:02d}.vtu"' in pvd for k in range(1, 6))


def test_bad_override_is_rejected_before_writing(tmp_path, capsys):
    out = tmp_path / "never"
    assert cli.main(["paper", "--out", str(out), "--elements", "0", "4", "4"]) == cli.EXIT_BAD_INPUT
    assert "elements" in capsys.readouterr().err
    assert not Path(out).exists()


def test_cli_local_methods_are_the_solver_ones():
    from fe_contact.stepping.model import LOCAL_METHODS

    assert paper_cli.LOCAL_METHODS == LOCAL_METHODS
