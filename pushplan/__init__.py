"""Push planning of deformable blocks on anisotropic-friction surfaces, built on
``fe_contact``.  Layers, each importing only from those above it in this list:

``errors``     the exception types and exit statuses
``config``     scenario schema, command codec, input files
``outputs``    the atomic writer, recordings and other file formats
``run``        the one FE driver loop, typed summaries, ``simulate``
``planning``   reduced model, NLP, FE rollouts, the plan document
``mujoco``     MJCF import, co-simulation, comparison, export
``studies``    the paper reproduction, parameter sweeps
``cli``        one thin module per command
"""

from .config import Scenario, ScenarioError, load_scenario, parse_scenario
from .run import Run, simulate

SimulationResult = Run  # the name earlier versions exported

__all__ = ["Run", "Scenario", "ScenarioError", "SimulationResult", "load_scenario", "parse_scenario", "simulate"]
