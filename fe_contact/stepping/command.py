"""The command of one load step (:class:`Command`): the upper face's rigid motion
increment (SI units, radians)."""

from __future__ import annotations

import math
from dataclasses import dataclass


def _finite(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class Command:
    """One load step: rigid motion increment of the upper face.

    Parameters
    ----------
    dx, dy, dz : float
        Translation increment of the upper face, m (world frame).
    dtheta : float
        Rotation increment about the vertical axis through the current upper-face
        centre, rad, counter-clockwise seen from +z.
    """

    dx: float = 0.0
    dy: float = 0.0
    dz: float = 0.0
    dtheta: float = 0.0

    def __post_init__(self):
        for name in ("dx", "dy", "dz", "dtheta"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))

    @property
    def moves(self) -> bool:
        """The command moves the gripper."""
        return any((self.dx, self.dy, self.dz, self.dtheta))


@dataclass(frozen=True)
class PadLoad:
    """One load step of a frictional pad's release by load control (issue 39):
    the pad's total normal load at the end of the step is ``load`` (N, >= 0);
    its height is an unknown of the step, solved with the displacements and
    the contact forces (:mod:`fe_contact.stepping.pad_load`).

    Parameters
    ----------
    load : float
        Sum of the pad's normal contact forces at the end of the step, N.
    retreat : (float, float)
        Horizontal motion of the pad per unit of its rise, m/m (the release's
        path, :class:`fe_contact.stepping.release.Release`).
    """

    load: float
    retreat: tuple = (0.0, 0.0)

    def __post_init__(self):
        load = _finite("load", self.load)
        if load < 0:
            raise ValueError(f"load must be >= 0 N, got {load}")
        object.__setattr__(self, "load", load)
        if len(self.retreat) != 2:
            raise ValueError(f"retreat must be a pair (m/m), got {self.retreat!r}")
        object.__setattr__(self, "retreat", tuple(_finite(f"retreat[{i}]", v) for i, v in enumerate(self.retreat)))

    @property
    def moves(self) -> bool:
        """A load step moves the pad (its height is solved for)."""
        return True


@dataclass(frozen=True)
class LetGo(Command):
    """A bonded pad lets go (issue 39): the step after a bonded lift's put-down
    has brought the pad's normal force to zero while the pad still carries an
    in-plane force (an offset footprint: the block's friction on the floor
    locks it in as the plate sets the block down).  The pad opens: the upper
    face becomes free, the gripper does not move, and the block comes to
    equilibrium on the floor alone (:func:`fe_contact.stepping.held.let_go_step`)."""

    def __post_init__(self):
        super().__post_init__()
        if self.moves:
            raise ValueError(f"a LetGo step does not move the gripper, got {self!r}")
