"""Identification with the exact Jacobian of the FE rollout (issue 30): the same
estimates as with forward differences, from far fewer FE rollouts."""

import tomllib

import numpy as np

from pushplan.config.observations import Observations
from pushplan.config.scenario import parse_scenario
from pushplan.identify.fit import identify, scales
from pushplan.identify.noise import NoiseModel
from pushplan.run import drive
from pushplan.run.observations import observations_from_steps

SAME_ESTIMATE = 1e-6
"""Exact against forward-difference estimates, in the fit's parameter scales (mu 0.1, angle 1 deg)."""
FEWER_ROLLOUTS = 3.0
FOAM = """
name = "foam"
[block]
size = [0.02, 0.02, 0.01]
elements = [3, 3, 1]
quadrature = 2
[material]
young = 1e6
poisson = 0.3
[friction]
mu_x = {mu_x}
mu_y = {mu_y}
angle_deg = {angle_deg}
[[load]]
dz = -5e-4
[[load]]
distance = 1e-3
direction_deg = 0
repeat = 2
[[load]]
distance = 1e-3
direction_deg = 90
repeat = 2
[solver]
local_method = "newton"
"""


def foam(**friction):
    return parse_scenario(tomllib.loads(FOAM.format(**friction)))


def test_exact_jacobian_gives_the_same_estimates_from_fewer_rollouts():
    truth = foam(mu_x=0.6, mu_y=0.35, angle_deg=25.0)
    clean = observations_from_steps(drive(truth.model(), truth.commands).summary.steps)
    rng = np.random.default_rng(3)
    values = {k: v + (rng.normal(0, 1e-6, v.shape) if k in ("lower_x", "lower_y") else rng.normal(0, 0.01 * abs(v)))
              for k, v in clean.values.items() if k != "lower_yaw_deg"}
    obs, noise = Observations(clean.commands, values), NoiseModel(1e-6, 1e-3, 0.01)
    guess = foam(mu_x=0.5, mu_y=0.5, angle_deg=0.0)
    exact = identify(guess, obs, noise, exact=True, model_error=False)
    fd = identify(guess, obs, noise, exact=False, model_error=False)
    assert exact.converged and fd.converged and exact.exact_jacobian and not fd.exact_jacobian
    gap = np.abs(exact.estimate - fd.estimate) / scales(exact.names, exact.estimate)
    assert gap.max() <= SAME_ESTIMATE, (exact.estimate, fd.estimate)
    # one rollout per LM iteration, plus the start and the chi2 at the scenario's values
    assert exact.fe_rollouts <= exact.iterations + 2
    assert fd.fe_rollouts >= FEWER_ROLLOUTS * exact.fe_rollouts
    np.testing.assert_allclose(exact.sigma, fd.sigma, rtol=1e-3)


def test_a_foam_blocks_stiffness_is_fitted_with_the_exact_jacobian():
    # young of the hyperfoam law (issue 30 item 2): derivatives in the material constants for every law
    text = FOAM.replace("poisson = 0.3", 'poisson = 0.3\nmodel = "hyperfoam"')
    truth = parse_scenario(tomllib.loads(text.format(mu_x=0.6, mu_y=0.35, angle_deg=25.0)))
    obs = observations_from_steps(drive(truth.model(), truth.commands).summary.steps)
    obs = Observations(obs.commands, {k: v for k, v in obs.values.items() if k != "lower_yaw_deg"})
    guess = parse_scenario(tomllib.loads(text.replace("young = 1e6", "young = 7e5").format(mu_x=0.6, mu_y=0.35,
                                                                                          angle_deg=25.0)))
    noise, fit = NoiseModel(1e-6, 1e-3, 0.01), ("mu_x", "young")
    exact = identify(guess, obs, noise, fit=fit, exact=True, model_error=False)
    fd = identify(guess, obs, noise, fit=fit, exact=False, model_error=False)
    assert exact.converged and exact.exact_jacobian and not fd.exact_jacobian
    young = exact.names.index("young")
    assert abs(exact.estimate[young] - 1e6) <= 1e-6 * 1e6  # noise-free observations: the truth
    gap = np.abs(exact.estimate - fd.estimate) / scales(exact.names, exact.estimate)
    assert gap.max() <= SAME_ESTIMATE, (exact.estimate, fd.estimate)
    assert exact.fe_rollouts <= exact.iterations + 2 and fd.fe_rollouts > exact.fe_rollouts
