"""rerun recordings of pushes and plans (read back by :mod:`pushplan.outputs.recording_read`).

One :class:`Recorder` per run writes one ``.rrd`` file through its own
``rerun.RecordingStream`` (no global state, no viewer needed).  The file is
written under a temporary name and renamed by :meth:`Recorder.close`, so a
reader never sees half a recording.

Timelines: ``step`` (sequence, load-step index; step 0 is the undeformed block)
and ``load`` (sequence, cumulative travel of the upper-face centre in
nanometres, i.e. the sum of ``sqrt(dx^2 + dy^2 + dz^2)`` over the commands).
Plan data use ``planner_iteration``.  World coordinates in m, z up; the lower
face starts centred on the origin.

Entities (``Archetype:field`` columns in the file)::

    world/block          Mesh3D: surface of the deformed block; triangles static,
                         vertex positions and colours per step.  Lower-face
                         vertices are coloured by ``field`` (viridis, 0 -> dark
                         blue, the run's maximum -> yellow: one scale for the whole
                         run, written at close), other vertices grey.
    world/upper_face     LineStrips3D: centroid trajectory; Points3D: current centroid.
    world/lower_face     same for the lower face.
    world/contact        Points3D with class ids 0 stick / 1 slip / 2 separated
                         (AnnotationContext) and, per node, the fields as data:
                         ``slip``, ``slip_path`` (m), ``pressure`` (Pa), ``normal_force`` (N).
    world/contact/force  Arrows3D: contact force on each lower node (the run's longest
                         arrow = half the block height; one scale for the run).
    world/floor, world/friction, world/gripper
                         the plane, the friction ellipse and the gripper plate
                         (:mod:`pushplan.outputs.recording_scene`).
    run/colour_scale     AnyValues per step: ``field``, ``low``, ``high`` (SI) of the
                         colour scale and ``arrow_m_per_n``; the same at every step.
    legend               TextDocument per step: colour scale and arrow scale.
    plots/lower_direction_deviation_deg (angle from the upper- to the lower-face
    centroid travel; no point while the lower face sticks, ``null`` in summary.json),
    plots/lower_yaw_deg, plots/normal_force (N), plots/tangential_force (N, x and y:
    the floor's friction force on the block), plots/gripper_force (N, x, y, z: the
    force the gripper applies on the upper face, what a wrist force sensor reads),
    plots/newton_iterations, plots/contact_iterations    Scalars per step;
    plots/pad_slip (m, a frictional pad's slip over the upper face, summary.json's
    ``pad_slip``; no point for a bonded pad).
    run/phase            AnyValues per step: ``phase`` = ``command`` or ``release`` (as in
                         summary.json) and ``label``: ``press`` (a command that only
                         lowers the gripper), ``push`` (any other moving command),
                         ``hold`` (a zero command) or ``release``.
    markers              TextLog: one line where each labelled phase starts (``press:``,
                         ``push:``, ``hold:``, ``release:``), ``rest:`` at the step where
                         the block is at rest (:meth:`Recorder.log_rest`), a plan's verified
                         rest pose (:meth:`Recorder.log_rest_pose`) and the run's warnings
                         (:meth:`Recorder.log_warning`, level WARN).
    log                  TextLog: one line per step, errors for failed steps.
    run/info             TextDocument (static): JSON ``{"run_name", "field", "scenario"}``.
    run/step             AnyValues per step: the command ``dx, dy, dz`` (m),
                         ``dtheta_deg`` and the centroid displacements
                         ``lower_centroid``, ``upper_centroid`` (m, float64);
                         what ``pushplan replay`` re-executes and compares.

A path logged at the current step (:meth:`Recorder.log_path`, e.g. each re-plan of
``pushplan closed-loop``): ``plan/<name>`` LineStrips3D + Points3D of lower-face poses.

Plans (:meth:`Recorder.log_plan`, for the planner)::

    recorder.log_plan(target=(x, y, yaw), predicted=P, verified=V, naive=N, cost=c)

    target      (2,) or (3,): lower-face target pose (x, y[, yaw]), m and rad.
    predicted, verified, naive
                (n, 2) or (n, 3): lower-face poses (x, y[, yaw]) per step, m and
                rad, row 0 the pose before the first command.
    cost        (n_iter,): planner objective per planner iteration.

Every argument is optional; each call replaces what an earlier call logged
(``plan/target`` as a footprint box, ``plan/predicted``, ``plan/verified``,
``plan/naive`` as line strips with points and yaw arrows, ``plots/planner_cost``
on ``planner_iteration``).  With ``first_step`` the overlays are on the step
timeline (the path so far at each step), otherwise static.  A plan run logs its FE-verified rollout with
:meth:`Recorder.log_step` so that ``pushplan replay`` can re-execute it.

Determinism: the recording id is derived from the run name and the wall-clock
``log_time`` timeline and start-time property are left out unless the
environment sets ``RERUN_LOG_TIME`` to 1 / true / on / yes, so two runs of
the same scenario differ only in row and chunk ids
(``rerun rrd compare --unordered`` reports them equal).

rerun is imported inside functions only, so importing this module (for the CLI
parser) stays cheap.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import uuid
from pathlib import Path

import numpy as np

from fe_contact import BlockMesh, StepReport
from fe_contact import surface_quads

from ..config.commands import command_to_dict
from . import recording_scene as scene
from .recording_plan import PlanOverlays
from .atomic import commit_temporary, reserve_temporary

RECORDING_FILE = "recording.rrd"
FULL_DISK_BYTES = 2**20
"""Free space below which a failed write of the recording is taken for a full disk."""
FLUSH_TIMEOUT_S = 60.0
"""A flush of one step takes milliseconds; rerun's file writer can stall on a full disk."""
APPLICATION_ID = "pushplan"
FIELDS = {  # name: (description, display unit, factor SI -> display unit)
    "slip": ("accumulated slip (norm of the total tangential displacement)", "um", 1e6),
    "slip_path": ("slip path length", "um", 1e6),
    "pressure": ("contact pressure", "MPa", 1e-6),
}
_NAMESPACE = uuid.UUID("5f0d4f52-3c1e-4a8b-9a59-8f2b7d2f6a10")  # fixed: recording id = uuid5(run name)
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)
_GREY = np.array([170, 170, 170], np.uint8)
_STATUS_CLASSES = ((0, "stick", (40, 160, 70)), (1, "slip", (230, 120, 20)), (2, "separated", (140, 140, 140)))
_PLOTS = ("lower_direction_deviation_deg", "lower_yaw_deg", "normal_force", "tangential_force", "gripper_force",
          "newton_iterations", "contact_iterations", "pad_slip")
_PLOT_SOURCE = {"gripper_force": "upper_force"}  # plot name -> StepSummary attribute, where they differ


def phase_label(phase: str, command) -> str:
    """The recording's phase label of a step (module docstring): ``release``, or for a
    command ``press`` (only a lowering ``dz``), ``hold`` (zero) or ``push``."""
    if phase == "release":
        return "release"
    if command.dx == 0 and command.dy == 0 and command.dtheta == 0:
        return "press" if command.dz < 0 else "hold" if command.dz == 0 else "push"
    return "push"


def _degrees_text(value: float | None) -> str:
    return "- (the lower face has not moved)" if value is None else f"{value:.4f} deg"


def recording_id(run_name: str) -> str:
    """Deterministic recording id (UUID5 string) of a run name."""
    return str(uuid.uuid5(_NAMESPACE, run_name))


def colormap(values: np.ndarray, vmax: float) -> np.ndarray:
    """Viridis colours (n, 3) uint8 of ``values`` on the scale ``[0, vmax]``."""
    t = np.clip(np.asarray(values, float) / vmax, 0.0, 1.0) if vmax > 0 else np.zeros(np.shape(values))
    knots = np.linspace(0.0, 1.0, len(_VIRIDIS))
    rgb = np.stack([np.interp(t, knots, _VIRIDIS[:, c]) for c in range(3)], axis=-1)
    return np.round(rgb).astype(np.uint8)


def _surface(mesh: BlockMesh) -> tuple[np.ndarray, np.ndarray]:
    """Surface node ids (n_v,) and triangles (n_t, 3) indexing them."""
    quads = surface_quads(mesh)
    nodes, inverse = np.unique(quads, return_inverse=True)
    q = inverse.reshape(quads.shape)
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]], axis=0)
    return nodes, tris.astype(np.uint32)


def vertex_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit vertex normals (n_v, 3): area-weighted sum of the adjacent triangle normals."""
    p = positions[triangles]  # (n_t, 3 corners, 3)
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals = np.zeros_like(positions)
    np.add.at(normals, triangles.ravel(), np.repeat(face, 3, axis=0))
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


class Recorder(PlanOverlays):
    """rerun recording of one run (see the module docstring for its content).

    Parameters
    ----------
    path : path
        ``.rrd`` file to write; its folder must exist.
    run_name : str
        Names the recording and fixes its recording id.
    mesh : fe_contact.BlockMesh
        Mesh of the model whose steps are logged.
    field : str
        Lower-face colour field, one of ``FIELDS``.
    scenario : dict, optional
        Resolved scenario (``Scenario.to_dict()``, as in ``summary.json``); stored so
        that ``pushplan replay`` can rebuild the model.  ``block.elements`` and
        ``block.size`` are taken from ``mesh``.

    Raises
    ------
    ValueError
        Bad field, run name, mesh or path.
    """

    def __init__(self, path, run_name: str, mesh: BlockMesh, field: str = "slip", scenario: dict | None = None):
        import rerun as rr

        if field not in FIELDS:
            raise ValueError(f"field must be one of {tuple(FIELDS)}, got {field!r}")
        if not isinstance(run_name, str) or not run_name:
            raise ValueError(f"run_name must be a non-empty string, got {run_name!r}")
        if not isinstance(mesh, BlockMesh):
            raise ValueError(f"mesh must be a fe_contact.BlockMesh, got {type(mesh).__name__}")
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise ValueError(f"recording folder does not exist: {self.path.parent}")
        self._rr = rr
        self.mesh = mesh
        self.field = field
        self.run_name = run_name
        self._surface_nodes, self._triangles = _surface(mesh)
        lower_pos = np.full(mesh.n_nodes, -1)
        lower_pos[mesh.lower] = np.arange(mesh.lower.size)
        self._surface_lower = lower_pos[self._surface_nodes]  # (n_v,) index into lower arrays, -1 elsewhere
        self._lower_ref = mesh.nodes[mesh.lower].mean(axis=0)
        self._upper_ref = mesh.nodes[mesh.upper].mean(axis=0)
        self._lower_traj = [self._lower_ref]
        self._upper_traj = [self._upper_ref]
        self._travel = 0.0
        self._yaw = 0.0  # cumulative upper-face rotation, rad
        self._deferred: list[tuple] = []  # per step: (k, travel, field values, arrow origins, forces)

        self._tmp = reserve_temporary(self.path)
        log_time = os.environ.get("RERUN_LOG_TIME", "").strip().lower() in ("1", "true", "on", "yes")
        try:
            # chunks are cut by the explicit flush after each step only, never by a
            # wall-clock tick, so two runs chunk their data identically
            self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id(run_name),
                                             send_properties=log_time,
                                             batcher_config=rr.ChunkBatcherConfig.NEVER())
            self.stream.set_log_time_enabled(log_time)
            with _writing(self._tmp, self.path):
                self.stream.save(self._tmp, default_blueprint=self._blueprint(plan=False))
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        self.stream.send_recording_name(run_name)
        self._log_static(scenario)
        self._closed = False
        self._phase = "command"
        self._log_reference()

    def _log_static(self, scenario: dict | None) -> None:
        """The timeless entities: run info (with the scenario), axes, mesh topology,
        contact classes, plot series names, floor, friction ellipse."""
        rr, mesh, run_name, field = self._rr, self.mesh, self.run_name, self.field
        spec = None
        if scenario is not None:
            spec = json.loads(json.dumps(scenario))  # deep copy, JSON-ready
            spec.setdefault("block", {}).update(elements=list(mesh.divisions), size=list(mesh.size))
        log = self.stream.log
        log("run/info", rr.TextDocument(json.dumps({"run_name": run_name, "field": field, "scenario": spec}),
                                        media_type=rr.MediaType.TEXT), static=True)
        log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log("world/block", rr.Mesh3D.from_fields(triangle_indices=self._triangles), static=True)
        log("world/contact", rr.AnnotationContext(list(_STATUS_CLASSES)), static=True)
        log("plots/tangential_force", rr.SeriesLines(names=["x", "y"]), static=True)
        log("plots/gripper_force", rr.SeriesLines(names=["x", "y", "z"]), static=True)
        log("world/floor", scene.floor(rr, mesh.size), static=True)
        if spec is not None and "friction" in spec:
            log("world/friction", *scene.friction_ellipse(rr, mesh.size, spec["friction"]), static=True)

    # -- blueprint ---------------------------------------------------------------------
    def _blueprint(self, plan: bool):
        import rerun.blueprint as rrb

        plots = [rrb.TimeSeriesView(origin=f"/plots/{p}", name=p) for p in _PLOTS]
        if plan:
            plots.append(rrb.TimeSeriesView(origin="/plots/planner_cost", name="planner_cost"))
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Vertical(
                    rrb.Spatial3DView(origin="/", contents=["/world/**", "/plan/**"], name="block"),
                    rrb.Horizontal(rrb.TextLogView(origin="/log", name="log"),
                                   rrb.TextDocumentView(origin="/legend", name="legend")),
                    row_shares=[3, 1],
                ),
                rrb.Grid(*plots, grid_columns=2),
                column_shares=[3, 2],
            ),
            collapse_panels=True,
        )

    # -- steps -------------------------------------------------------------------------
    def _set_step(self, k: int, travel: float | None = None) -> None:
        self.stream.set_time("step", sequence=int(k))
        self.stream.set_time("load", sequence=int(round((self._travel if travel is None else travel) * 1e9)))

    def _log_reference(self) -> None:
        rr = self._rr
        self._set_step(0)
        colours = np.broadcast_to(_GREY, (self._surface_nodes.size, 3)).copy()
        colours[self._surface_lower >= 0] = colormap(np.zeros(1), 0.0)[0]
        positions = self.mesh.nodes[self._surface_nodes]
        self.stream.log("world/block", rr.Mesh3D.from_fields(
            vertex_positions=positions, vertex_normals=vertex_normals(positions, self._triangles),
            vertex_colors=colours))
        for name, traj in (("upper_face", self._upper_traj), ("lower_face", self._lower_traj)):
            self.stream.log(f"world/{name}", rr.LineStrips3D([np.array(traj)]), rr.Points3D([traj[-1]]))
        self.stream.log("world/gripper", scene.gripper(rr, self.mesh.size, self._upper_ref, 0.0))
        self._flush()

    def log_step(self, report: StepReport, summary=None) -> None:
        """Log one load step.

        Parameters
        ----------
        report : fe_contact.StepReport
            A failed step is logged as an error line only (its state was rejected).
        summary : pushplan.run.StepSummary
            The step's summary (required for a converged step): the plotted numbers
            are taken from it so they equal ``summary.json``.
        """
        rr = self._rr
        if self._closed:
            raise ValueError(f"recording {self.path} is closed")
        if not isinstance(report, StepReport):
            raise ValueError(f"report must be a fe_contact.StepReport, got {type(report).__name__}")
        c = report.command
        if not report.converged:
            self._set_step(report.step_index)
            self.stream.log("log", rr.TextLog(
                f"step {report.step_index} failed ({report.status.value}): {report.message}",
                level=rr.TextLogLevel.ERROR))
            self._flush()
            return
        if summary is None or summary.step != report.step_index:
            raise ValueError(f"log_step needs the StepSummary of step {report.step_index}")
        self._travel += math.sqrt(c.dx**2 + c.dy**2 + c.dz**2)
        self._yaw += c.dtheta
        self._set_step(report.step_index)
        deformed = self.mesh.nodes + report.displacement
        self._log_block(deformed)
        self._log_trajectories(report)
        self._log_contact(report, deformed)
        self._log_numbers(report, summary)
        self._flush()

    def _log_block(self, deformed: np.ndarray) -> None:
        """Deformed block surface (its colours are logged at :meth:`close`, on one scale)."""
        positions = deformed[self._surface_nodes]
        self.stream.log("world/block", self._rr.Mesh3D.from_fields(
            vertex_positions=positions, vertex_normals=vertex_normals(positions, self._triangles)))

    def _log_trajectories(self, report: StepReport) -> str:
        rr = self._rr
        self._lower_traj.append(self._lower_ref + np.asarray(report.lower_centroid))
        self._upper_traj.append(self._upper_ref + np.asarray(report.upper_centroid))
        for face, traj in (("upper_face", self._upper_traj), ("lower_face", self._lower_traj)):
            self.stream.log(f"world/{face}", rr.LineStrips3D([np.array(traj)]), rr.Points3D([traj[-1]]))
        self.stream.log("world/gripper", scene.gripper(rr, self.mesh.size, self._upper_traj[-1], self._yaw))

    def _log_contact(self, report: StepReport, deformed: np.ndarray) -> None:
        """Node status points with the lower-face fields as data (``slip``, ``slip_path``
        in m, ``pressure`` in Pa, ``normal_force`` in N per node); the force arrows are
        logged at :meth:`close`, on one scale."""
        rr = self._rr
        origins = deformed[self.mesh.lower]
        self.stream.log("world/contact", rr.Points3D(origins, class_ids=np.asarray(report.node_status, np.uint16),
                                                     radii=rr.Radius.ui_points(3.0)),
                        rr.AnyValues(**{name: np.asarray(getattr(report, name), float) for name in FIELDS},
                                     normal_force=np.asarray(report.reaction_local, float)[:, 0]))
        self._deferred.append((report.step_index, self._travel, np.asarray(getattr(report, self.field), float),
                               origins, np.asarray(report.reaction_world, float)))

    def _log_fixed_scales(self) -> None:
        """Every step's lower-face colours and force arrows on one scale for the run
        (``[0, largest value of any step]``, ``largest force of any step`` = half the block
        height), the scales logged as data (``run/colour_scale``) and in the legend."""
        rr = self._rr
        if not self._deferred:
            return
        name, unit, factor = FIELDS[self.field]
        vmax = max(float(v.max()) if v.size else 0.0 for _, _, v, _, _ in self._deferred)
        fmax = max(float(np.linalg.norm(f, axis=1).max()) if f.size else 0.0 for *_, f in self._deferred)
        scale = 0.5 * self.mesh.size[2] / fmax if fmax > 0 else 0.0
        on_lower = self._surface_lower >= 0
        for k, travel, values, origins, forces in self._deferred:
            self._set_step(k, travel)
            colours = np.broadcast_to(_GREY, (self._surface_nodes.size, 3)).copy()
            colours[on_lower] = colormap(values[self._surface_lower[on_lower]], vmax)
            self.stream.log("world/block", rr.Mesh3D.from_fields(vertex_colors=colours))
            self.stream.log("world/contact/force", rr.Arrows3D(origins=origins, vectors=forces * scale))
            self.stream.log("run/colour_scale", rr.AnyValues(field=self.field, unit="SI", low=0.0, high=vmax,
                                                              arrow_m_per_n=scale))
            self.stream.log("legend", rr.TextDocument(
                f"## step {k}\n\n**block colour**: {name} on the lower face, viridis from 0 {unit} (dark blue) "
                f"to {vmax * factor:.6g} {unit} (yellow), one scale for the whole run; other faces grey.\n\n"
                f"**contact arrows**: force on the block, {scale * 1e3:.6g} mm per N (longest of the run "
                f"{fmax:.6g} N).\n\n**contact points**: green stick, orange slip, grey separated; select one "
                "for its slip, slip path, pressure and normal force.\n\n**orange ellipse**: the friction "
                "ellipse of the surface (axes t_x, t_y scaled by mu_x, mu_y).",
                media_type=rr.MediaType.MARKDOWN))

    def _log_numbers(self, report: StepReport, summary) -> None:
        """Plots, the replayable ``run/step`` row and the log line."""
        rr, c, log = self._rr, report.command, self.stream.log
        for p in _PLOTS:
            value = getattr(summary, _PLOT_SOURCE.get(p, p))
            if value is not None:  # a sticking lower face has no direction: no point
                log(f"plots/{p}", rr.Scalars(np.atleast_1d(np.asarray(value, float))))
        phase = getattr(summary, "phase", "command")
        label = phase_label(phase, c)
        log("run/phase", rr.AnyValues(phase=phase, label=label))
        if label != self._phase:
            log("markers", rr.TextLog(f"release: step {report.step_index} is the first release step"
                                      if label == "release" else f"{label}: from step {report.step_index}"))
        self._phase = label
        log("run/step", rr.AnyValues(
            **command_to_dict(c),
            lower_centroid=np.asarray(report.lower_centroid, float),
            upper_centroid=np.asarray(report.upper_centroid, float)))
        log("log", rr.TextLog(
            f"step {report.step_index}: command ({c.dx:.6g}, {c.dy:.6g}, {c.dz:.6g}) m, "
            f"{math.degrees(c.dtheta):.6g} deg; lower-face direction deviation "
            f"{_degrees_text(summary.lower_direction_deviation_deg)}, "
            f"lower yaw {summary.lower_yaw_deg:.4f} deg, N {summary.normal_force:.6g} N, "
            f"newton {report.newton_iterations}, contact {report.contact_iterations}",
            level=rr.TextLogLevel.INFO))

    def _flush(self) -> None:
        """Flush the stream (a full disk is an OSError, :func:`_writing`)."""
        with _writing(self._tmp, self.path):
            self.stream.flush(timeout_sec=FLUSH_TIMEOUT_S)

    # -- closing -----------------------------------------------------------------------
    def log_rest(self, rest) -> None:
        """Mark the step at which the block is at rest after a release
        (:class:`pushplan.run.summary.RestSummary`) on the ``markers`` log."""
        self._set_step(rest.step)
        lo = rest.lower_centroid
        self.stream.log("markers", self._rr.TextLog(
            f"rest: after the {rest.mode} release, step {rest.step}, lower face ({lo[0]:.6g}, {lo[1]:.6g}) m, "
            f"yaw {rest.lower_yaw_deg:.6g} deg"))
        self._flush()

    def log_warning(self, text: str, step: int | None = None) -> None:
        """A warning of the run (e.g. :func:`pushplan.run.summary.pad_slip_warning`) on the
        ``markers`` log at ``step`` (default: the current one), level WARN."""
        if step is not None:
            self._set_step(step)
        self.stream.log("markers", self._rr.TextLog(text, level=self._rr.TextLogLevel.WARN))
        self._flush()

    def close(self) -> Path:
        """Flush, disconnect and move the finished file into place; returns its path."""
        if not self._closed:
            self._closed = True
            self._log_fixed_scales()
            try:
                self._flush()
                with _writing(self._tmp, self.path):
                    self.stream.disconnect()
            except BaseException:
                self._tmp.unlink(missing_ok=True)  # nothing half-written left behind
                raise
            commit_temporary(self._tmp, self.path)
        return self.path

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextlib.contextmanager
def _writing(tmp: Path, path: Path):
    """A full disk while rerun writes ``tmp`` (its file-writer reports it as a
    ``RuntimeError``: "Failed to encode LogMsg ... No space left on device", from
    ``save``, ``flush`` or ``disconnect``) becomes the ``OSError(ENOSPC)`` naming
    ``path`` that the CLI reports on one line (exit 1); any other RuntimeError is a bug
    and keeps its traceback."""
    try:
        yield
    except RuntimeError as exc:
        st = os.statvfs(tmp.parent)
        if "No space left" not in str(exc) and st.f_bavail * st.f_frsize >= FULL_DISK_BYTES:
            raise
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path)) from exc
