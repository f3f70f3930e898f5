"""The same commands through our FE model and MuJoCo's rigid and flex models
(:func:`compare`), the result as typed data (:class:`Comparison`) and its plot.

``comparison.json`` holds ``scene``, ``settings`` (the ``[mujoco]`` table),
``flex_mu``, ``commands``, ``limitations`` (:data:`PAIR_AXES_LIMITATION`) and per model ``description``, ``wall_s``, ``summary``
(final and largest twist / deviation, final lower-face displacement) and ``steps``
(:class:`~pushplan.mujoco.records.ComparisonStep`, world frame, m / degrees).
"""

from __future__ import annotations

import io
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from fe_contact import Command, Model

from ..config.commands import commands_to_list
from ..config.mujoco import BridgeSettings
from ..errors import InputError, SolverFailure
from ..outputs.atomic import atomic_write_bytes, atomic_write_json
from ..run.driver import drive
from .flex import flex_run
from .mjmodel import check_mujoco_work
from .records import ComparisonStep
from .rigid import rigid_force_run, rigid_weld_run
from .scene import MjcfScene
from .trajectory import gripper_trajectory

MODEL_NOTES = {
    "fe": "this FE model: deformable block, anisotropic elliptic friction, displacement-driven upper face",
    "rigid_weld": "MuJoCo rigid box with the MJCF <pair> friction, welded to the mocap gripper (stiff weld)",
    "rigid_force": "MuJoCo rigid box with the MJCF <pair> friction, pushed by a horizontal force at its "
                   "centre of mass (force_factor x sliding threshold, until it travelled the command length)",
    "flex_isotropic": "MuJoCo 3D flex of the block's size and material, top pinned to the gripper, "
                      "isotropic friction flex_mu (MuJoCo flex contacts take no anisotropy)",
}

PAIR_AXES_LIMITATION = (
    "MuJoCo's <pair> friction axes are fixed in the world (t1 = world +y, t2 = world -x, from the contact "
    "normal alone): they cannot turn with the block, so rigid_weld and rigid_force keep the friction ellipse "
    "world-aligned whatever the box's yaw; the FE friction axes are those of the floor, at the imported angle"
)
"""What ``compare`` states with every result (``comparison.json`` ``limitations``, terminal)."""


@dataclass(frozen=True)
class ModelRun:
    """One compared model: its steps and wall time (s)."""

    name: str
    steps: tuple[ComparisonStep, ...]
    wall_s: float

    def summary(self) -> dict:
        """Final and largest |twist| / |deviation| / |lower-face yaw| (degrees), final
        lower-face displacement (m, world frame)."""
        last = self.steps[-1].to_dict() if self.steps else {}
        return {
            "final_lower_yaw_deg": last.get("lower_yaw_deg", 0.0),
            "max_abs_lower_yaw_deg": max((abs(math.degrees(r.lower_yaw)) for r in self.steps), default=0.0),
            "final_twist_deg": last.get("twist_deg", 0.0),
            "final_deviation_deg": last.get("deviation_deg", 0.0),
            "max_abs_twist_deg": max((abs(math.degrees(r.twist)) for r in self.steps), default=0.0),
            "max_abs_deviation_deg": max((abs(math.degrees(r.deviation)) for r in self.steps), default=0.0),
            "final_lower": last.get("lower"),
        }

    def to_dict(self) -> dict:
        return {"description": MODEL_NOTES[self.name], "wall_s": self.wall_s, "summary": self.summary(),
                "steps": [r.to_dict() for r in self.steps]}


@dataclass(frozen=True)
class Comparison:
    """The result of :func:`compare`; ``models`` in the order run."""

    scene: MjcfScene
    settings: BridgeSettings
    flex_mu: float
    commands: tuple[Command, ...]
    models: dict[str, ModelRun]

    def to_dict(self) -> dict:
        """The ``comparison.json`` form."""
        return {"scene": self.scene.to_dict(), "settings": self.settings.to_dict(), "flex_mu": self.flex_mu,
                "commands": commands_to_list(self.commands), "limitations": [PAIR_AXES_LIMITATION],
                "models": {name: run.to_dict() for name, run in self.models.items()}}


def fe_run(scene: MjcfScene, commands: Sequence[Command], fe_model: Model) -> tuple[ComparisonStep, ...]:
    """Our FE model driven by ``commands``, its face poses in the world frame.

    Raises
    ------
    SolverFailure
        An FE step did not converge (its number and message).
    """
    run = drive(fe_model, commands)
    if not run.completed:
        raise SolverFailure(f"FE step {len(run.reports)} failed: {run.reports[-1].message}")
    scale = max(scene.scenario.size)
    out = []
    for k, rep in enumerate(run.reports, start=1):
        up, low = scene.to_world(rep.upper_centroid), scene.to_world(rep.lower_centroid)
        out.append(ComparisonStep.measure(k, up, up, low, rep.lower_yaw, scale))
    return tuple(out)


def _check(scene: MjcfScene, commands: tuple, models: Sequence[str]) -> None:
    if not commands:
        raise InputError("no commands: give a command list or a scenario with [[load]] steps")
    unknown = [name for name in models if name not in MODEL_NOTES]
    if unknown:
        raise InputError(f"unknown comparison model {unknown[0]!r} (known: {', '.join(MODEL_NOTES)})")
    if not scene.source:
        raise InputError("compare needs a scene imported from an MJCF file")


def compare(scene: MjcfScene, commands: Sequence[Command] | None = None, settings: BridgeSettings | None = None,
            fe_model: Model | None = None, models: Sequence[str] = tuple(MODEL_NOTES), out_dir=None) -> Comparison:
    """Same commands through our FE model and MuJoCo's rigid and flex models.

    Each model reports per command a :class:`~pushplan.mujoco.records.ComparisonStep`:
    ``drive`` (gripper-carried upper-face centre displacement, or the commanded one),
    ``upper`` / ``lower`` (block face centroid displacements), ``twist`` (upper to
    lower: the block's deformation twist), ``deviation`` (drive to lower), world frame.

    With ``out_dir``, writes ``comparison.json`` and ``comparison.png`` (lower-face
    trajectories).

    Raises
    ------
    InputError
        Unknown model name, no commands, a scene not imported from a file.
    SolverFailure
        An FE step did not converge.
    """
    settings = settings or BridgeSettings(scene=scene.source)
    commands = tuple(scene.scenario.commands if commands is None else commands)
    _check(scene, commands, models)
    m = scene.mj_model("compare")
    traj = gripper_trajectory(scene, m, commands, settings.gripper, settings.control_period)
    check_mujoco_work(len(commands), settings.control_period + settings.settle_time, m.opt.timestep)
    n_move = max(1, int(round(settings.control_period / m.opt.timestep)))
    n_settle = int(round(settings.settle_time / m.opt.timestep))
    s = scene.scenario
    flex_mu = settings.flex_mu if settings.flex_mu is not None else math.sqrt(s.mu_x * s.mu_y)
    runners = {
        "fe": lambda: fe_run(scene, commands, fe_model or s.model()),
        "rigid_weld": lambda: rigid_weld_run(scene, traj, n_move, n_settle),
        "rigid_force": lambda: rigid_force_run(scene, commands, traj, n_move, n_settle, settings.force_factor),
        "flex_isotropic": lambda: flex_run(scene, commands, traj, n_move, n_settle, settings.flex_points, flex_mu),
    }
    runs = {}
    for name in models:
        t0 = time.perf_counter()
        steps = runners[name]()
        runs[name] = ModelRun(name, steps, time.perf_counter() - t0)
    result = Comparison(scene, settings, flex_mu, commands, runs)
    if out_dir is not None:
        out = Path(out_dir)
        atomic_write_json(out / "comparison.json", result.to_dict())
        atomic_write_bytes(out / "comparison.png", plot_png(result))
    return result


def plot_png(result: Comparison) -> bytes:
    """PNG of the lower-face centroid trajectories (mm, world frame) and lower-face yaw
    per command (degrees) of every model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_yaw) = plt.subplots(1, 2, figsize=(11, 5))
    first = next(iter(result.models.values()))
    drive_xy = np.array([[0.0, 0.0]] + [r.drive[:2] for r in first.steps]) * 1e3
    ax.plot(drive_xy[:, 0], drive_xy[:, 1], "k--", label="drive (upper face)")
    for name, run in result.models.items():
        xy = np.array([[0.0, 0.0]] + [r.lower[:2] for r in run.steps]) * 1e3
        last = run.steps[-1]
        ax.plot(xy[:, 0], xy[:, 1], "o-", ms=3,
                label=f"{name}: twist {math.degrees(last.twist):.2f}°, "
                      f"deviation {math.degrees(last.deviation):.2f}°, yaw {math.degrees(last.lower_yaw):.3f}°")
        ax_yaw.plot([0] + [r.step for r in run.steps], [0.0] + [math.degrees(r.lower_yaw) for r in run.steps],
                    "o-", ms=3, label=name)
    ax.set_xlabel("world x (mm)")
    ax.set_ylabel("world y (mm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("lower-face centroid")
    ax.legend(fontsize=7)
    ax_yaw.set_xlabel("command")
    ax_yaw.set_ylabel("lower-face yaw (deg)")
    ax_yaw.set_title("lower-face yaw")
    ax_yaw.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
