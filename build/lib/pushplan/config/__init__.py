"""Inputs: the one schema of scenarios and the tables other commands read from them
(``[plan]``, ``[mujoco]``, ``[sweep]``), the command codec and input files.
Imports nothing from ``run``, ``planning``, ``mujoco``, ``studies`` or ``cli``."""

from .commands import command_from_dict, command_to_dict, commands_from_list, commands_to_list, load_commands
from .scenario import Scenario, ScenarioError, load_scenario, parse_scenario

__all__ = ["Scenario", "ScenarioError", "command_from_dict", "command_to_dict", "commands_from_list",
           "commands_to_list", "load_commands", "load_scenario", "parse_scenario"]
