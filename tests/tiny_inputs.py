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


def killing_case(task: dict) -> dict:
    """A sweep-pool case for the fault tests (importable by spawned workers): counts its
    attempts in ``task["dir"]`` and, while ``task["kill"]`` attempts remain, kills its own
    worker with SIGKILL (as the OOM killer would), deterministically, mid-case."""
    import os
    import signal
    from pathlib import Path

    marker = Path(task["dir"]) / f"case{task['id']}"
    attempt = len(list(marker.parent.glob(f"{marker.name}.attempt*"))) + 1
    (marker.parent / f"{marker.name}.attempt{attempt}").touch()
    if attempt <= task["kill"]:
        os.kill(os.getpid(), signal.SIGKILL)
    return {"id": task["id"], "attempt": attempt, "pid": os.getpid()}
