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


def test_a_bad_footprint_exits_2_with_one_line(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text(GRIPPER + "pad_size = [0.02, 0.02]\npad_offset = [0.0, 0.02]\n")
    assert main(["simulate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "gripper.pad_offset" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()
