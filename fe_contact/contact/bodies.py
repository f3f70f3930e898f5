"""Rigid planar contact bodies: the floor, the gripper pad, any further plane.

A contact body is data: the block's nodes that may touch it, its plane's unit
normal ``n`` (world, pointing from the body into the block), a point ``p`` of
the plane in the reference pose, and its elliptic friction cone (``mu_x``,
``mu_y`` along the orthotropy axes ``t_x``, ``t_y`` of its frame).  Each
contact node lives in the frame of the body it touches, rows ``(n, t_x,
t_y)`` (``t_x`` the orthotropy axis, ``t_y = n x t_x``), so the local problem
stacks every body's contacts and solves them with one projection and one
flexibility matrix (paper eq. 42-45, each contact its own cone).  A side pad
or a fence is one more body.

Kinematics of contact ``i`` of a body whose plane has moved rigidly over the
step to point ``p'`` (m): the normal gap and the tangential slip increment,

    g_i = n . (x_i - p'),          du_t,i = T_t,i (du_i - dv_i),      m,

``x_i = X_i + U_i`` the node's position, ``du_i`` its displacement increment
over the step and ``dv_i`` the increment of the body's point that coincided
with the node at the start of the step (zero for the fixed floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .friction import local_frame

__all__ = ["FOOTPRINT_SHAPES", "ContactBody", "ContactSet", "Footprint", "horizontal_frame", "stack_bodies"]

FOOTPRINT_SHAPES = ("rectangle", "disc")


def horizontal_frame(up: bool, angle: float) -> np.ndarray:
    """Rotation (3, 3) from world to the contact frame ``(n, t_x, t_y)`` of a
    horizontal plane: ``n = e_z`` (``up``: the floor) or ``-e_z`` (a pad
    above the block), ``t_x = (cos angle, sin angle, 0)`` (``angle`` from world
    x, counter-clockwise seen from +z, rad), ``t_y = n x t_x``: the orthotropy
    frame :func:`~fe_contact.contact.friction.local_frame`, with ``n`` and
    ``t_y`` reversed for a pad."""
    T = local_frame(angle)
    return T if up else T * np.array([[-1.0], [1.0], [-1.0]])


@dataclass(frozen=True)
class Footprint:
    """The gripper pad's footprint on the block's upper face: the upper-face
    nodes under it are the ones the pad touches (held by a bonded pad,
    contacts of a frictional one); the rest of the face is free.

    A node of reference position ``(x, y)`` is under the pad when

        rectangle:  |x - c_x| <= a_x / 2 + eps  and  |y - c_y| <= a_y / 2 + eps,
        disc:       |(x, y) - c| <= r + eps,

    ``c`` = the face's centre + ``offset``, ``eps = 1e-9`` of the face's
    larger side (a node on the pad's edge is under it).

    Parameters
    ----------
    shape : str
        ``"rectangle"`` or ``"disc"`` (:data:`FOOTPRINT_SHAPES`).
    size : (2,) float
        Rectangle: its sides ``(a_x, a_y)`` along world x, y, m; disc: its
        diameter twice ``(2 r, 2 r)``, m.  > 0.
    offset : (2,) float
        Pad centre from the upper face's centre, m (default centred).
    """

    shape: str
    size: tuple[float, float]
    offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        if self.shape not in FOOTPRINT_SHAPES:
            raise ValueError(f"shape must be one of {FOOTPRINT_SHAPES}, got {self.shape!r}")
        for name, lo in (("size", 0.0), ("offset", None)):
            v = tuple(float(x) for x in np.ravel(getattr(self, name)))
            if len(v) != 2 or not all(math.isfinite(x) for x in v) or (lo is not None and min(v) <= lo):
                raise ValueError(f"{name} must be 2 finite numbers{' > 0' if lo is not None else ''} (m), "
                                 f"got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        if self.shape == "disc" and self.size[0] != self.size[1]:
            raise ValueError(f"a disc's size is its diameter twice, got {self.size!r}")

    def select(self, face_xy: np.ndarray, centre, sides) -> np.ndarray:
        """Mask (n,) of the face nodes ``face_xy`` (n, 2), m, under the pad, on a
        face of centre ``centre`` (2,) and sides ``sides`` (2,), m.

        Raises
        ------
        ValueError
            The pad reaches outside the face (message starts with ``offset``
            or ``size``), or no node is under it.
        """
        half, sides = np.asarray(self.size) / 2, np.asarray(sides, dtype=float)
        eps = 1e-9 * float(sides.max())
        if np.any(np.abs(self.offset) + half > sides / 2 + eps):
            key = "size" if np.any(half > sides / 2 + eps) else "offset"
            raise ValueError(f"{key}: the pad ({self.shape} {list(self.size)} m at offset {list(self.offset)} m) "
                             f"reaches outside the upper face ({sides.tolist()} m)")
        rel = face_xy - (np.asarray(centre, dtype=float)[:2] + self.offset)
        if self.shape == "disc":
            under = np.hypot(rel[:, 0], rel[:, 1]) <= half[0] + eps
        else:
            under = np.all(np.abs(rel) <= half + eps, axis=1)
        if not under.any():
            raise ValueError(f"size: no upper-face node is under the pad ({self.shape} {list(self.size)} m at "
                             f"offset {list(self.offset)} m): enlarge it or refine the mesh")
        return under


@dataclass(frozen=True)
class ContactBody:
    """A rigid plane the block may touch.

    Parameters
    ----------
    name : str
    nodes : ndarray of int, shape (n,)
        Block nodes that may touch it.
    frame : ndarray, shape (3, 3)
        World to local rotation, rows ``(n, t_x, t_y)`` (:func:`horizontal_frame`).
    point : ndarray, shape (3,)
        A point of the plane in the reference pose, m.
    mu_x, mu_y : float
        Friction coefficients along ``t_x``, ``t_y`` (>= 0).
    moves_with_gripper : bool
        The plane follows the gripper's commanded pose (the pad); else it is fixed.
    """

    name: str
    nodes: np.ndarray
    frame: np.ndarray
    point: np.ndarray
    mu_x: float
    mu_y: float
    moves_with_gripper: bool = False

    def __post_init__(self):
        for k in ("mu_x", "mu_y"):
            v = float(getattr(self, k))
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{self.name} {k} must be finite and >= 0, got {v}")
            object.__setattr__(self, k, v)
        frame = np.array(self.frame, dtype=float)
        if frame.shape != (3, 3) or not np.allclose(frame @ frame.T, np.eye(3), atol=1e-12):
            raise ValueError(f"{self.name} frame must be a (3, 3) rotation, got {frame!r}")
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "point", np.array(self.point, dtype=float).reshape(3))
        object.__setattr__(self, "nodes", np.array(self.nodes, dtype=np.int64).ravel())


@dataclass(frozen=True)
class ContactSet:
    """Every body's contacts stacked, the first body's first (arrays per contact).

    Attributes
    ----------
    nodes : ndarray of int, shape (n_c,)
    frames : ndarray, shape (n_c, 3, 3)
        World to local rotation of each contact.
    uniform : bool
        One frame for all (a floor alone): products take the fast path.
    mu_x, mu_y : ndarray, shape (n_c,)
    body : ndarray of int, shape (n_c,)
        Index of the body each contact belongs to.
    bodies : tuple of ContactBody
    """

    nodes: np.ndarray
    frames: np.ndarray
    uniform: bool
    mu_x: np.ndarray
    mu_y: np.ndarray
    body: np.ndarray
    bodies: tuple

    def to_world(self, r: np.ndarray) -> np.ndarray:
        """World vectors (n_c, 3) of local ones ``r`` (n_c, 3): ``T_i^T r_i``."""
        if self.uniform:
            return r @ self.frames[0]
        return np.einsum("cij,ci->cj", self.frames, r)

    def to_local(self, v: np.ndarray) -> np.ndarray:
        """Local vectors (n_c, 3) of world ones ``v`` (n_c, 3): ``T_i v_i``."""
        if self.uniform:
            return v @ self.frames[0].T
        return np.einsum("cij,cj->ci", self.frames, v)

    def rotate_blocks(self, W: np.ndarray, band: int = 256) -> None:
        """``W <- T W T^T`` in place for a (3 n_c, 3 n_c) matrix of 3x3 blocks
        (world to local frames), a band of block rows at a time."""
        n = self.nodes.size
        m = 3 * n
        blocks = W.reshape(n, 3, n, 3)
        for i in range(0, n, band):
            rows = blocks[i:i + band]
            if self.uniform:
                T = self.frames[0]
                rows[...] = (T @ rows.reshape(-1, 3, m)).reshape(rows.shape) @ T.T
            else:
                left = np.einsum("aij,ajbk->aibk", self.frames[i:i + band], rows)
                rows[...] = np.einsum("aibk,blk->aibl", left, self.frames)

    def kinematics(self, x: np.ndarray, du: np.ndarray, gripper_motion: np.ndarray, gripper_shift: np.ndarray):
        """Gaps (n_c,), m, and world slip increments (n_c, 3), m, of the contacts.

        Parameters
        ----------
        x : ndarray, shape (n_c, 3)
            Current positions of the contact nodes, m.
        du : ndarray, shape (n_c, 3)
            Their displacement increments over the step, m.
        gripper_motion : ndarray, shape (n_c, 3)
            Increment over the step of the gripper point that coincided with
            each node at the start of the step (used for bodies that move with
            the gripper), m.
        gripper_shift : ndarray, shape (3,)
            Translation of the gripper from the reference pose, m.
        """
        moving = np.array([b.moves_with_gripper for b in self.bodies])[self.body]
        points = np.array([b.point for b in self.bodies])[self.body] + np.where(moving[:, None], gripper_shift, 0.0)
        normals = self.frames[:, 0, :]
        gap = np.einsum("ci,ci->c", normals, x - points)
        slip = du - np.where(moving[:, None], gripper_motion, 0.0)
        return gap, slip


def stack_bodies(bodies) -> ContactSet:
    """The :class:`ContactSet` of ``bodies`` (a sequence of :class:`ContactBody`)."""
    bodies = tuple(bodies)
    if not bodies:
        raise ValueError("at least one contact body is needed")
    nodes = np.concatenate([b.nodes for b in bodies])
    if np.unique(nodes).size != nodes.size:
        raise ValueError("a node may touch one contact body only")
    sizes = [b.nodes.size for b in bodies]
    frames = np.concatenate([np.broadcast_to(b.frame, (b.nodes.size, 3, 3)) for b in bodies])
    uniform = len(bodies) == 1
    mu_x = np.concatenate([np.full(s, b.mu_x) for s, b in zip(sizes, bodies, strict=True)])
    mu_y = np.concatenate([np.full(s, b.mu_y) for s, b in zip(sizes, bodies, strict=True)])
    body = np.repeat(np.arange(len(bodies)), sizes)
    return ContactSet(nodes, np.ascontiguousarray(frames), uniform, mu_x, mu_y, body, bodies)
