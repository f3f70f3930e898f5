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


PLAN = BASE.replace("""[[load]]
distance = 0.32e-3
direction_deg = 45.0
""", "") + """
[plan]
x = 1e-4
y = 0.0
steps = 2
max_step = 1e-4
planning_elements = [2, 2, 1]
planning_quadrature = 2
"""
"""The tiny block with a press only and a two-step [plan] (plan, closed-loop)."""

OBSERVATIONS = """dx,dy,dz,dtheta_deg,lower_x,lower_y,lower_yaw_deg,force_x,force_y,force_z
0.0,0.0,-0.0001,0.0,-2.19719850209398e-21,0.0,2.3085779093447824e-18,-3.637978807091713e-12,2.546585164964199e-11,-997452.7952005654
0.00022627416997969525,0.00022627416997969522,0.0,0.0,0.00014517654575216978,0.00021314941029278837,0.004775781353188105,254968.00495330247,41277.27191845185,-945644.6403330781
"""
"""What `simulate --observations` writes for BASE (press, one push): identify fits it in one iteration."""
