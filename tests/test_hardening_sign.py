"""Issue 43, one sign convention for forces (docs/conventions.md): a MuJoCo wrist force
sensor's log, turned into the world frame and fed to ``identify`` as it is (no sign
change), is explained by the FE model at the scene's friction; the opposite sign is not.

The arm scene of docs/mujoco-coupling.md: the press (20 periods) and 10 periods of the
push, the 2 x 2 x 1 mesh; the observed commands are the hand's own motion per period."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="the MuJoCo extra is not installed")

from fe_contact import Command  # noqa: E402
from pushplan.config.observations import Observations  # noqa: E402
from pushplan.identify import NoiseModel, identify  # noqa: E402
from pushplan.identify.forward import IdentificationError  # noqa: E402
from pushplan.mujoco import attach, open_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PERIODS = 30


def wrist_log():
    """(commands, sensor forces in the FE frame (K, 3) N) of the arm's push, one row a period."""
    scene, settings = open_scene(ROOT / "scenarios" / "mujoco_arm.toml")
    m = mujoco.MjModel.from_xml_path(str(ROOT / "scenarios" / "mujoco_arm.xml"))
    d = mujoco.MjData(m)
    coupler = attach(m, d, scene, gripper="hand", fe_model=scene.scenario.model(elements=(2, 2, 1)))
    commands = scene.scenario.commands[:PERIODS]
    plan = np.vstack([np.zeros(3), np.cumsum(scene.to_world([[c.dx, c.dy, c.dz] for c in commands]), axis=0)])
    n_sub = round(settings.control_period / m.opt.timestep)
    site, hand = m.site("wrist").id, m.body("hand").id
    start = d.xpos[hand].copy()
    moved, forces = [], []
    for k in range(PERIODS):
        for j in range(1, n_sub + 1):
            d.ctrl[:] = plan[k] + (plan[k + 1] - plan[k]) * j / n_sub
            mujoco.mj_step(m, d)
        assert coupler.couple().converged
        moved.append(d.xpos[hand] - start)
        forces.append(d.site_xmat[site].reshape(3, 3) @ d.sensordata[0:3])  # what the sensor reads, world
    steps = np.diff(np.vstack([np.zeros(3), scene.to_fe(np.array(moved))]), axis=0)
    cmds = tuple(Command(*(float(v) for v in s)) for s in steps)
    return replace(scene.scenario, elements=(2, 2, 1)), cmds, scene.to_fe(np.array(forces))  # the coupled mesh


def test_a_wrist_sensor_log_goes_to_identify_as_it_is():
    scenario, cmds, force = wrist_log()
    assert force[0, 2] < 0  # the hand presses the block down: a force on the block
    noise = NoiseModel(force_noise=0.01, force_noise_rel=0.01)
    chi2 = {}
    for sign in (1.0, -1.0):
        obs = Observations(cmds, {"force_x": sign * force[:, 0], "force_y": sign * force[:, 1],
                                  "force_z": sign * force[:, 2]})
        try:
            result = identify(scenario, obs, noise, ("mu_x", "mu_y"), model_error=False)
        except IdentificationError:  # the fit ran off to a friction the FE cannot solve: not explained
            assert sign < 0
            chi2[sign] = np.inf
            continue
        chi2[sign] = result.chi2_initial / result.n_values
        if sign > 0:
            np.testing.assert_allclose(result.estimate, [scenario.mu_x, scenario.mu_y], rtol=0.05)
    assert chi2[1.0] < 1.0 < 1e3 < chi2[-1.0], chi2
