"""Inputs shared by the CLI test modules: a tiny scenario (2 x 2 x 1 hex8: a press and
one push, solved in milliseconds) and a two-case sweep of it."""

BASE = """
name = "tiny"
[block]
size = [0.02, 0.02, 0.01]
elements = [2, 2, 1]
quadrature = 2
[material]
young = 210e9
poisson = 0.3
[friction]
mu_x = 0.3
mu_y = 0.1
[[load]]
dz = -1e-4
[[load]]
distance = 0.32e-3
direction_deg = 45.0
[solver]
local_method = "newton"
"""

SWEEP = """
base = "base.toml"
workers = 1
[grid]
"friction.mu_y" = [0.1, 0.2]
"""
