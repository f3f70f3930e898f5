"""The plan overlays of a :class:`~pushplan.outputs.recording.Recorder` (its module
docstring lists them): the target box and the predicted, verified and naive lower-face
paths (:meth:`PlanOverlays.log_plan`), a path that changes along a run
(:meth:`PlanOverlays.log_path`) and a plan's verified rest pose
(:meth:`PlanOverlays.log_rest_pose`).  A mixin: it uses the recorder's stream, mesh and
step timeline."""

from __future__ import annotations

import math

import numpy as np

from . import recording_scene as scene


def _poses(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim != 2 or a.shape[1] not in (2, 3) or a.shape[0] < 1:
        raise ValueError(f"{name} must have shape (n, 2) or (n, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


class PlanOverlays:
    """Plan overlays on ``plan/...`` of a recorder (``self._rr``, ``self.stream``,
    ``self.mesh``, ``self._set_step``, ``self._blueprint``, ``self._flush``)."""

    def log_plan(self, target=None, predicted=None, verified=None, naive=None, cost=None,
                 first_step: int | None = None) -> None:
        """Log a plan (see the module docstring for shapes and units).

        With ``first_step`` (the step index of pose row 0, e.g. the number of press
        steps), the overlays follow the step timeline: at step ``first_step + k`` the
        paths up to row ``k`` and the target; without it they are static.

        Raises
        ------
        ValueError
            A pose array of the wrong shape or with non-finite values.
        """
        rr = self._rr
        if self._closed:
            raise ValueError(f"recording {self.path} is closed")
        size = self.mesh.size
        arrow = 0.25 * min(size[0], size[1])
        overlays = {name: _poses(name, value) for name, value in
                    (("predicted", predicted), ("verified", verified), ("naive", naive)) if value is not None}
        box = None
        if target is not None:
            t = np.asarray(target, float).ravel()
            if t.shape not in ((2,), (3,)) or not np.all(np.isfinite(t)):
                raise ValueError(f"target must be (x, y) or (x, y, yaw) finite numbers, got {target!r}")
            box = scene.target_box(rr, size, t)
        rows = max((len(p) for p in overlays.values()), default=1)
        self.stream.disable_timeline("load")  # plan rows are steps, not travel
        for k in ([None] if first_step is None else range(rows)):
            if k is not None:
                self.stream.set_time("step", sequence=int(first_step + k))
            if box is not None:
                self.stream.log("plan/target", box, static=k is None)
            for name, poses in overlays.items():
                shown = poses if k is None else poses[:k + 1]
                self.stream.log(f"plan/{name}", *scene.pose_path(rr, name, shown, arrow), static=k is None)
        if cost is not None:
            c = np.asarray(cost, float).ravel()
            if c.size == 0:
                raise ValueError("cost must hold at least one value")
            self.stream.send_columns(
                "plots/planner_cost",
                indexes=[rr.TimeColumn("planner_iteration", sequence=np.arange(c.size))],
                columns=rr.Scalars.columns(scalars=c),
            )
            self.stream.send_blueprint(self._blueprint(plan=True), make_active=False, make_default=True)

    def log_path(self, name: str, poses, colour=(160, 80, 220)) -> None:
        """Log lower-face poses ``(n, 2 or 3)`` (m, rad) as ``plan/<name>`` at the current step
        (after :meth:`log_step`): a path that changes along the run."""
        xy = _poses(name, poses)[:, :2]
        xyz = np.column_stack([xy, np.zeros(len(xy))])
        self.stream.log(f"plan/{name}", self._rr.LineStrips3D([xyz], colors=[colour], labels=[name]),
                        self._rr.Points3D(xyz, colors=[colour]))

    def log_rest_pose(self, step: int, loaded, rest) -> None:
        """A plan's verified rest: at ``step`` (its last release step) the path ``plan/rest``
        from the ``loaded`` lower-face pose to the ``rest`` one ((2,) or (3,), m and rad, the
        springback the release verified) and a ``rest:`` marker."""
        poses = _poses("rest", np.vstack([np.asarray(loaded, float).ravel()[:2], np.asarray(rest, float).ravel()[:2]]))
        self._set_step(step)
        xyz = np.column_stack([poses, np.zeros(2)])
        self.stream.log("plan/rest", self._rr.LineStrips3D([xyz], colors=[(40, 170, 90)], labels=["rest"]),
                        self._rr.Points3D(xyz[1:], colors=[(40, 170, 90)], radii=[0.02 * min(self.mesh.size[:2])]))
        r = np.asarray(rest, float).ravel()
        yaw = f", yaw {math.degrees(r[2]):.6g} deg" if r.size > 2 else ""
        self.stream.log("markers", self._rr.TextLog(
            f"rest: the verified release, step {step}: lower face at rest ({r[0]:.6g}, {r[1]:.6g}) m{yaw}"))
        self._flush()
