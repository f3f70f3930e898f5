"""Push planning of deformable blocks on anisotropic-friction surfaces, built on
``fe_contact``: scenarios, simulation runs, CLI (planner, MuJoCo bridge and rerun
logging live in their own modules at the edges)."""

from .scenario import Scenario, ScenarioError, load_scenario, parse_scenario
from .simulate import SimulationResult, simulate

__all__ = ["Scenario", "ScenarioError", "SimulationResult", "load_scenario", "parse_scenario", "simulate"]
