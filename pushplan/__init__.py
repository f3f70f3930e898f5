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

The names below are imported on first use, so ``import pushplan.cli`` stays cheap.
"""

import importlib

_EXPORTS = {
    "Scenario": "pushplan.config", "ScenarioError": "pushplan.config", "load_scenario": "pushplan.config",
    "parse_scenario": "pushplan.config", "InputError": "pushplan.errors", "SolverFailure": "pushplan.errors",
    "Run": "pushplan.run", "simulate": "pushplan.run",
}

__all__ = ["InputError", "Run", "Scenario", "ScenarioError", "SolverFailure", "load_scenario", "parse_scenario",
           "simulate"]  # the keys of _EXPORTS (tests/test_structure.py checks)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'pushplan' has no attribute {name!r}")
