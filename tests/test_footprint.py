"""Issue 39 item 6: a pad smaller than the face (``Model(footprint=Footprint(...))``,
``[gripper] pad_shape / pad_size / pad_radius / pad_offset``).  A 20 x 20 mm pad on a
40 x 30 x 10 mm block meshed 4 x 3 x 2 (nodes every 10 mm): 3 x 2 upper nodes under it."""

import math

import numpy as np
import pytest

from fe_contact import Command, Footprint, Friction, Material, Model, SolverOptions, block_mesh, run
from pushplan.cli import main
from pushplan.config.scenario import parse_scenario
from pushplan.errors import InputError

SIZE, DIVISIONS = (0.04, 0.03, 0.01), (4, 3, 2)
PAD = Footprint("rectangle", (0.02, 0.02))
LOADS = [Command(dz=-1e-4), Command(dx=2e-4, dy=1e-4, dtheta=math.radians(0.5))]


def model(footprint=None, pad=None):
    return Model(block_mesh(SIZE, DIVISIONS), Material(2e6, 0.3, density=1000.0), Friction(0.6, 0.25),
                 quadrature=2, pad=pad, footprint=footprint, options=SolverOptions(newton_tol=1e-10))


def under(m):
    xy = m.mesh.nodes[m.mesh.upper, :2]
    return m.mesh.upper[(np.abs(xy[:, 0]) <= 0.01 + 1e-12) & (np.abs(xy[:, 1]) <= 0.01 + 1e-12)]


def nodal_force(m, state):
    """``f_int - f_weight - f_contact`` per node (n_nodes, 3), N: what the drive applies."""
    from fe_contact.fem.elasticity import internal_force

    f, _ = internal_force(m.geometry, m.mesh.elements, state.displacement, m.material)
    f = f.reshape(-1, 3) - m.body_force.reshape(-1, 3)
    np.subtract.at(f, m.contacts.nodes, m.contacts.to_world(state.reaction))
    return f


def test_a_bonded_pad_holds_only_the_nodes_under_it():
    m = model(PAD)
    assert sorted(m.held_nodes) == sorted(under(m)) and m.held_nodes.size == 6
    state, reports = run(m, LOADS)
    assert all(r.converged for r in reports)
    f = np.linalg.norm(nodal_force(m, state), axis=1)
    free_upper = np.setdiff1d(m.mesh.upper, m.held_nodes)
    assert f[m.held_nodes].min() > 1e-3 * f[m.held_nodes].max() > 0  # every held node carries pad force
    assert f[free_upper].max() < 1e-8 * f[m.held_nodes].max()  # the rest of the face is free
    # the free part of the face is not flat: the pad's edges press in more than its outside
    top = state.displacement[m.mesh.upper, 2]
    assert np.ptp(top[np.isin(m.mesh.upper, free_upper)]) > 1e-6


def test_a_frictional_pad_touches_only_the_nodes_under_it():
    m = model(PAD, pad=Friction(0.9, 0.9))
    pad_nodes = m.contacts.nodes[m.n_lower:]
    assert sorted(pad_nodes) == sorted(under(m))
    state, reports = run(m, LOADS)
    assert all(r.converged for r in reports)
    pad = state.reaction[m.n_lower:]
    assert np.all(pad[:, 0] > 0)  # every pad contact closed
    f = np.linalg.norm(nodal_force(m, state), axis=1)
    assert f[np.setdiff1d(m.mesh.upper, pad_nodes)].max() < 1e-8 * pad[:, 0].max()


def test_the_whole_face_footprint_is_todays_model():
    whole = Footprint("rectangle", SIZE[:2])
    for pad in (None, Friction(0.9, 0.9)):
        a, ra = run(model(None, pad), LOADS)
        b, rb = run(model(whole, pad), LOADS)
        assert np.array_equal(a.displacement, b.displacement)
        assert np.array_equal(ra[-1].upper_force, rb[-1].upper_force)


def test_a_disc_and_an_offset_select_their_nodes():
    m = model(Footprint("disc", (0.02, 0.02), offset=(0.01, 0.0)))  # radius 10 mm about x = 10 mm
    xy = m.mesh.nodes[m.held_nodes, :2]
    assert np.all(np.hypot(xy[:, 0] - 0.01, xy[:, 1]) <= 0.01 + 1e-12)
    assert m.held_nodes.size == 2  # (10, +-5) mm; (0, +-5) and (20, +-5) are 11.2 mm away
    inside = np.hypot(m.mesh.nodes[m.mesh.upper, 0] - 0.01, m.mesh.nodes[m.mesh.upper, 1]) <= 0.01 + 1e-12
    assert sorted(m.held_nodes) == sorted(m.mesh.upper[inside])


GRIPPER = """
name = "s"
[block]
size = [0.04, 0.03, 0.01]
elements = [4, 3, 2]
[material]
young = 2e6
poisson = 0.3
[friction]
mu_x = 0.6
mu_y = 0.25
[[load]]
dz = -1e-4
[gripper]
"""


def parse(extra):
    import tomllib

    return parse_scenario(tomllib.loads(GRIPPER + extra))


def test_the_scenario_reads_and_writes_the_footprint():
    sc = parse('pad_size = [0.02, 0.02]\npad_offset = [0.005, 0.0]\n')
    assert sc.footprint == Footprint("rectangle", (0.02, 0.02), (0.005, 0.0))
    assert parse_scenario(sc.to_dict()) == sc
    assert sc.model().held_nodes.size == 4  # x = 0, 10 mm; y = -5, 5 mm
    disc = parse('pad_shape = "disc"\npad_radius = 0.006\n')
    assert disc.footprint.size == (0.012, 0.012) and parse_scenario(disc.to_dict()) == disc
    assert parse("").footprint is None and parse("").to_dict().get("gripper") is None


@pytest.mark.parametrize("extra, key", [
    ('pad_size = [0.05, 0.02]', "gripper.pad_size"),  # wider than the face
    ('pad_size = [0.02, 0.02]\npad_offset = [0.015, 0.0]', "gripper.pad_offset"),  # pushed off the face
    ('pad_size = [-0.02, 0.02]', "gripper.pad_size[0]"),  # negative
    ('pad_size = [0.004, 0.004]\npad_offset = [0.005, 0.0]', "gripper.pad_size"),  # between nodes: none under it
    ('pad_shape = "disc"\npad_radius = 0.003\npad_offset = [0.005, 0.0]', "gripper.pad_radius"),
    ('pad_shape = "disc"\npad_size = [0.01, 0.01]', "gripper.pad_shape"),
    ('pad_shape = "square"\npad_size = [0.01, 0.01]', "gripper.pad_shape"),
])
def test_bad_footprints_are_refused_naming_the_key(extra, key):
    with pytest.raises(InputError) as e:
        parse(extra)
    assert str(e.value).startswith(key) and "\n" not in str(e.value)


def test_footprint_messages_say_what_is_missing_in_plain_numbers():
    """pad_offset alone (no size, no shape) names the missing pad_size, not pad_radius;
    a pad outside the face prints plain floats (not np.float64(...))."""
    with pytest.raises(InputError) as e:
        parse("pad_offset = [0.005, 0.0]")
    assert str(e.value).startswith("gripper.pad_size is missing") and "pad_radius (m)" in str(e.value)
    with pytest.raises(InputError) as e:
        parse('pad_shape = "disc"')
    assert str(e.value).startswith("gripper.pad_radius is missing")
    with pytest.raises(InputError) as e:
        parse("pad_size = [0.02, 0.02]\npad_offset = [0.015, 0.0]")
    assert "([0.04, 0.03] m)" in str(e.value) and "np." not in str(e.value)


def test_a_bad_footprint_exits_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text(GRIPPER + "pad_size = [0.02, 0.02]\npad_offset = [0.0, 0.02]\n")
    assert main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "gripper.pad_offset" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


OFFSET = {"rectangle": Footprint("rectangle", (0.02, 0.02), (0.01, 0.0)),
          "disc": Footprint("disc", (0.022, 0.022), (-0.009, 0.004))}


def offset_release(footprint):
    from fe_contact import Release, release_to_rest

    m = model(footprint)
    state, reports = run(m, [Command(dz=-1e-4), Command(dx=2e-4, dy=1e-4)])
    state, release, rest = release_to_rest(m, state, Release("lift", 4), reports[-1])
    return m, state, release, rest


@pytest.mark.parametrize("name", list(OFFSET))
def test_a_bonded_offset_pad_lets_go_and_the_block_settles(name):
    """Set down from an offset pad, the block's lower face sticks to the floor while
    it straightens: at zero vertical force the pad still holds 0.3 W in the plane,
    which no plate height removes (the release ran out its 200 steps).  The pad lets
    go (LetGo): settled, N = W, the pad carries nothing and no node is held."""
    from fe_contact import LetGo

    m, state, release, rest = offset_release(OFFSET[name])
    assert isinstance(release[-1].command, LetGo) and release[-2].command.__class__ is Command
    assert np.linalg.norm(release[-2].upper_force[:2]) > 0.2 * m.weight  # what the pad held before it let go
    assert rest.settled, rest.reason
    assert release[-1].normal_force == pytest.approx(m.weight, rel=1e-9) and rest.pad_force == 0.0
    assert len(release) < 30  # not the 200-step cap
    f = np.linalg.norm(nodal_force(m, state), axis=1)
    assert f[m.held_nodes].max() <= 1e-9 * m.weight  # the upper face is free: no force under the pad either


def test_the_let_go_threshold_does_not_move_the_rest(monkeypatch):
    """LET_GO_FORCE (the vertical force at which an offset pad lets go) is a device:
    its effect, 1e-6 W against 1e-9 W, on the rest pose is below 1e-9 of the lag."""
    import fe_contact.stepping.release as release_module

    _, a, _, _ = offset_release(OFFSET["rectangle"])
    monkeypatch.setattr(release_module, "LET_GO_FORCE", 1e-9)
    _, b, release, rest = offset_release(OFFSET["rectangle"])
    assert rest.settled and abs(release[-2].upper_force[2]) < 1e-8  # let go nearer zero
    lag = 2.236e-4  # the push, m
    assert np.abs(a.displacement - b.displacement).max() <= 1e-9 * lag


def test_the_let_go_is_not_differentiated():
    from fe_contact import Release, rollout_derivatives

    d = rollout_derivatives(model(OFFSET["rectangle"]), [Command(dz=-1e-4), Command(dx=2e-4, dy=1e-4)],
                            parameters=("young",), release=Release("lift", 4))
    assert d.status.value != "converged" and "let-go" in d.message


@pytest.mark.parametrize("friction", ["", "friction = 0.9\n"])
def test_fields_npz_holds_the_pad_force_of_each_node_under_it(tmp_path, friction):
    """fields.npz: ``pad_nodes`` are the nodes under a 20 x 20 mm pad on the 40 x 30 mm
    block, ``pad_force`` (steps, n_pad, 3) each one's pad force, every one loaded, summing
    to the step's ``upper_force`` of summary.json."""
    import json

    path = tmp_path / "s.toml"
    path.write_text(GRIPPER.replace("poisson = 0.3", "poisson = 0.3\ndensity = 1000.0") + friction +
                    "pad_size = [0.02, 0.02]\n[[load]]\ndx = 2e-4\ndy = 1e-4\n")
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--quiet", "--no-recording"]) == 0
    steps = json.loads((out / "summary.json").read_text())["steps"]
    with np.load(out / "fields.npz") as f:
        nodes, force = f["pad_nodes"], f["pad_force"]
    m = parse(friction + "pad_size = [0.02, 0.02]\n").model()
    assert sorted(nodes) == sorted(under(m)) and force.shape == (len(steps), 6, 3)
    assert np.all(np.abs(force[:, :, 2]) > 0)  # every node under the pad presses
    for s, fs in zip(steps, force, strict=True):
        assert np.allclose(fs.sum(axis=0), s["upper_force"], rtol=1e-12, atol=1e-15)


def test_a_let_go_moves_nothing_and_is_a_bonded_pads():
    from fe_contact import LetGo, initial_state
    from fe_contact.stepping.step import step

    with pytest.raises(ValueError, match="does not move"):
        LetGo(dz=1e-4)
    m = model(None, pad=Friction(0.9, 0.9))
    with pytest.raises(ValueError, match="bonded pad"):
        step(m, initial_state(m), LetGo())
