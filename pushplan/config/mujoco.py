"""The ``[mujoco]`` table of a scenario: where the MJCF scene is, which of its bodies
play block, floor and gripper, and the settings of the co-simulation and comparison.

    [mujoco]
    scene = "mujoco_push.xml"      # MJCF, relative to the scenario TOML
    block = "block"                # body (holding one box geom) or box geom
    floor = "floor"                # plane geom
    gripper = "gripper"            # body or site carrying the upper face (mocap to follow commands)
    control_period = 0.05          # s of MuJoCo time per command / FE step (< 10 s)
    settle_time = 0.05             # s held after each command in the rigid and flex comparisons (< 10 s)
    flex_points = [3, 3, 2]        # flexcomp grid points of the isotropic flex comparison (2 to 16 each)
    flex_mu = 0.12                 # isotropic flex friction; absent: sqrt(mu_x mu_y)
    force_factor = 1.2             # force-driven rigid box: push force / sliding threshold (> 1)

``bridge_settings(settings.to_dict())`` gives ``settings`` back.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from ..limits import MAX_CONTROL_PERIOD, MAX_FLEX_POINTS
from .validate import Table, integer

MUJOCO_KEYS = (
    "scene", "block", "floor", "gripper", "control_period", "settle_time",
    "flex_points", "flex_mu", "force_factor",
)


@dataclass(frozen=True)
class BridgeSettings:
    """A validated ``[mujoco]`` table (SI units); ``flex_mu`` None is sqrt(mu_x mu_y)."""

    scene: str = ""
    block: str = "block"
    floor: str = "floor"
    gripper: str = "gripper"
    control_period: float = 0.05
    settle_time: float = 0.05
    flex_points: tuple[int, int, int] = (3, 3, 2)
    flex_mu: float | None = None
    force_factor: float = 1.2

    def to_dict(self) -> dict:
        """The table as JSON-ready values (``flex_mu`` None when unset): what
        :func:`bridge_settings` reads back into equal settings."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in fields(self)}


def _grid_points(key: str, value) -> int:
    """A :func:`~pushplan.config.validate.triple` check: flexcomp points per direction, >= 2."""
    return integer(key, value, 2, MAX_FLEX_POINTS)


def bridge_settings(table: dict, name: str = "mujoco") -> BridgeSettings:
    """Validate a ``[mujoco]`` table (or :meth:`BridgeSettings.to_dict`).

    Raises
    ------
    InputError
        Unknown key or bad value, named by its path (``mujoco.force_factor``).
    """
    t = Table(table, name, MUJOCO_KEYS)
    default = BridgeSettings()
    flex_mu = t.data.get("flex_mu")
    return BridgeSettings(
        **{k: t.string(k, getattr(default, k)) for k in ("scene", "block", "floor", "gripper")},
        control_period=t.number("control_period", default.control_period, positive=True, maximum=MAX_CONTROL_PERIOD),
        settle_time=t.number("settle_time", default.settle_time, nonneg=True, maximum=MAX_CONTROL_PERIOD),
        flex_points=t.triple("flex_points", _grid_points, default.flex_points),
        flex_mu=None if flex_mu is None else t.number("flex_mu", nonneg=True),
        force_factor=t.number("force_factor", default.force_factor, lo=1.0),  # above the sliding threshold
    )


__all__ = ["MUJOCO_KEYS", "BridgeSettings", "bridge_settings"]
