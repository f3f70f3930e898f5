"""A plan at the file boundary: the ``plan.json`` document, its re-executable command
list and the ``recording.rrd`` of the verified rollout."""

from __future__ import annotations

import math

import numpy as np

from fe_contact import BlockMesh, Model

from ..config.commands import commands_to_list, planar_commands
from ..config.fingerprint import scenario_fingerprint
from ..config.plan import PlanSpec
from ..config.scenario import pad_friction_dict
from ..run.summary import StepSummary
from .result import PlanResult
from .target import pose_error


POSE_UNITS = ("m", "m", "deg")
"""The units of a pose row ``[x, y, yaw]`` in the files (``plan.json``, ``closed_loop.json``:
their ``pose_units``); the API and the service take radians."""


def _poses_json(poses: np.ndarray) -> list[list[float]]:
    """(n, 3) poses as ``[x, y, yaw_deg]`` rows (:data:`POSE_UNITS`)."""
    p = np.asarray(poses, float)
    return [[float(r[0]), float(r[1]), math.degrees(float(r[2]))] for r in p]


def _error_json(pose, spec: PlanSpec) -> dict:
    pos, yaw = pose_error(pose, spec)
    return {"position": pos, "position_rel_travel": pos / spec.travel if spec.travel > 0 else None,
            "yaw_deg": math.degrees(yaw) if spec.yaw_targeted else None}


def _commands_json(commands: np.ndarray) -> list[dict]:
    """(K, 3) planned commands ``(dx, dy, dtheta)`` in the command-file format."""
    return commands_to_list(planar_commands(commands))


def plan_commands_json(result: PlanResult) -> list[dict]:
    """The re-executable command list (press, then planned commands)."""
    return commands_to_list(s.command for s in result.press_steps) + _commands_json(result.commands)


def plan_document(result: PlanResult) -> dict:
    """The ``plan.json`` content.

    ``commands`` is the full re-executable sequence (press, then the K planned
    commands) in the :mod:`pushplan.config.commands` format; poses are lists of
    ``[x (m), y (m), yaw (deg)]`` of the lower face, row 0 after the press, row k
    after planned command k (simulate step ``press_steps + k``).  ``solver.fe_rollouts``
    counts every rollout per mesh: calibration, correction and the naive baseline
    (``naive`` is None for a plan made without it).
    """
    spec, sol, state = result.spec, result.solution, result.spec.target_state
    return {
        "pose_units": list(POSE_UNITS),
        "scenario": result.scenario.to_dict(),
        "scenario_fingerprint": scenario_fingerprint(result.scenario.to_dict()),
        "plan": spec.to_dict(),
        "status": result.status,
        "message": result.message,
        "commands": plan_commands_json(result),
        "press_steps": len(result.press_steps),
        "planned_commands": _commands_json(result.commands),
        "poses": {
            "predicted": _poses_json(sol.lower),
            "predicted_upper": _poses_json(sol.upper),
            "planning_fe": _poses_json(result.planning.lower) if result.planning is not None else None,
            "verified": _poses_json(result.verified.lower),
            "verified_upper": _poses_json(result.verified.upper),
        },
        "modifier": {"x": float(result.modifier[0]), "y": float(result.modifier[1]),
                     "yaw_deg": math.degrees(float(result.modifier[2]))},
        "final_error": _error_json(result.verified.final(state), spec),
        "final_poses": _final_poses_json(result.verified, spec),
        "naive": None if result.naive is None else {
            "commands": _commands_json(result.naive.commands),
            "verified_poses": _poses_json(result.naive.lower),
            "final_error": _error_json(result.naive.final(state), spec),
            "final_poses": _final_poses_json(result.naive, spec),
        },
        "reduced_model": {**result.params.to_dict(), "springback": result.springback.to_dict()},
        "meshes": {
            "planning": {"elements": list(spec.planning_elements), "quadrature": spec.planning_quadrature},
            "verification": {"elements": list(result.scenario.elements), "quadrature": result.scenario.quadrature},
        },
        "solver": {
            "nlp": "casadi Opti + ipopt",
            "refinement": result.refinement,
            "nlp_solves": sum(1 for it in result.iterations if it.resolved),
            "nlp_success": sol.success,
            "nlp_iterations": sol.iterations,
            "fe_rollouts": result.rollouts,
            "wall_time_s": result.timings,
            "iterations": [it.to_dict() for it in result.iterations],
        },
        "release": _release_json(result),
    }


def _final_poses_json(rollout, spec: PlanSpec) -> dict:
    """The rollout's final lower-face pose loaded and at rest (None without a
    release), each ``[x, y, yaw_deg]`` with its error against the target."""
    poses = {"loaded": rollout.lower[-1], "rest": rollout.rest}
    return {name: None if pose is None else {"pose": _poses_json([pose])[0], "error": _error_json(pose, spec)}
            for name, pose in poses.items()}


def _release_json(result: PlanResult) -> dict:
    """How the gripper lets go, which pose the target is for, and ``pad_slip``: how far a frictional pad slid
    on the upper face during the verified push (m, :attr:`~.rollouts.Rollout.pad_slip`)."""
    release = result.scenario.release
    return {"mode": None if release is None else release.mode,
            "steps": None if release is None else release.steps,
            "gripper_friction": pad_friction_dict(result.scenario.pad),
            "pad_slip": result.verified.pad_slip,
            "target_state": result.spec.target_state,
            "meaning": ("the target is the lower-face pose at rest after the release" if result.spec.target_state
                        == "rest" else "the target is the lower-face pose under load, the gripper still holding "
                                       "the upper face after the last command")}


def write_recording(result: PlanResult, path, verification_model: Model) -> None:
    """``recording.rrd``: the verified FE rollout (press and plan) and the plan overlays."""
    fn, args = recording_job(result, path, verification_model.mesh)
    fn(*args)


def recording_job(result: PlanResult, path, mesh: BlockMesh) -> tuple:
    """:func:`write_recording` as ``(function, arguments)``, the arguments plain picklable
    data (reports, summaries, arrays): what :class:`~pushplan.outputs.recording_process.
    RecordingProcess` runs in its child.  ``mesh``: the verification mesh
    (:meth:`~pushplan.config.scenario.Scenario.mesh`, no model needed)."""
    spec = result.spec
    resolved = {**result.scenario.to_dict(), "load": plan_commands_json(result)}
    released = tuple(r for r in result.verified.release_reports if r.converged)
    reports = (*result.press_reports, *result.verified.reports, *released)
    steps = (*result.press_steps, *result.verified.steps,  # built once, by the driver
             *(StepSummary.from_report(r, "release") for r in released))
    dims = 3 if spec.yaw_targeted else 2
    overlay = dict(target=np.array(spec.target)[:dims], predicted=result.solution.lower[:, :dims],
                   verified=result.verified.lower[:, :dims],
                   naive=None if result.naive is None else result.naive.lower[:, :dims],
                   cost=[it.objective for it in result.iterations], first_step=len(result.press_reports))
    rest = None
    if result.verified.rest is not None and released:  # the verified release, its rest pose beside the target
        rest = dict(step=released[-1].step_index, loaded=result.verified.lower[-1][:dims],
                    rest=np.asarray(result.verified.rest)[:dims])
    return _write_plan_recording, (path, f"plan_{result.scenario.name}", mesh, resolved,
                                   reports, steps, overlay, rest)


def _write_plan_recording(path, name: str, mesh, resolved: dict, reports, steps, overlay: dict,
                          rest: dict | None = None) -> None:
    from ..outputs.recording import Recorder

    with Recorder(path, name, mesh, scenario=resolved) as rec:
        for rep, summary in zip(reports, steps, strict=True):
            rec.log_step(rep, summary)
        rec.log_plan(**overlay)
        if rest is not None:
            rec.log_rest_pose(**rest)
