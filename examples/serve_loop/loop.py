"""A robot's control loop on ``pushplan serve`` (docs/service.md, "A control loop").

Two processes: ``pushplan serve`` (started here, or ``--address`` of a running one) holds
the warm planner; this process is the robot: a MuJoCo scene (``scene.xml``: a mocap
gripper on a steel block whose floor has 30 % more friction than the planner's model,
``model.toml``) with the FE block coupled in (``pushplan.mujoco.attach``), stepped at a
fixed control period.

The loop, ``--periods`` control periods of ``control_period`` s of MuJoCo time each
(``truth.toml``'s ``[mujoco]``), split evenly between the moves: the press, then each
planned push.  In every period the gripper moves its share of the current move and MuJoCo
steps; at a move's last period the coupler steps the FE block once with the whole move
(as ``pushplan closed-loop`` steps its truth: one FE step per command).  After each push
the robot reads the block's pose from MuJoCo (world -> block frame), reports it with the
pushes executed (``Replan(closed_loop=True)``: the re-plan ``closed-loop`` makes) and
executes the first command of the answer.

Prints one line per push and the final pose; ``--out FILE`` writes them as JSON
(``final_pose``: x, y (m), yaw (rad) of the lower face from rest, block frame; ``pose_units``
says so: ``closed_loop.json``'s poses are ``[x, y, yaw]`` in m, m, deg, its ``pose_units``).
``--compare closed_loop.json`` (from ``pushplan closed-loop model.toml --truth truth.toml``)
checks that the loop ended where closed-loop ends, to ``--within`` m (exit 1 if not).
``--realtime`` holds every period to the wall clock and counts the periods that overran.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


class Robot:
    """The MuJoCo scene of ``truth`` with the FE block coupled in and a mocap gripper the
    loop moves (world frame, m, rad)."""

    def __init__(self, truth: Path):
        import mujoco

        from pushplan.mujoco import attach, open_scene
        from pushplan.mujoco.frames import quat_mul, quat_z

        self.mj, self._quat = mujoco, lambda yaw: quat_mul(quat_z(yaw), self.quat0)
        self.scene, settings = open_scene(truth)
        self.m = self.scene.mj_model("the control loop")
        self.d = mujoco.MjData(self.m)
        mujoco.mj_forward(self.m, self.d)
        self.period = settings.control_period
        self.substeps = int(round(self.period / self.m.opt.timestep))
        self.coupler = attach(self.m, self.d, self.scene, gripper=settings.gripper, control_period=self.period)
        self.mocap = int(self.m.body_mocapid[mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_BODY, settings.gripper)])
        self.centre = self.d.mocap_pos[self.mocap].copy()  # the gripper carries the upper face's centre
        self.quat0, self.yaw, self.periods = self.d.mocap_quat[self.mocap].copy(), 0.0, 0

    def move(self, command, periods: int, pace=None) -> None:
        """Move the gripper by ``command`` (dx, dy, dz, dtheta; block frame, m and rad)
        over ``periods`` control periods, then step the FE block once with the whole move."""
        dx, dy, dz, dtheta = command
        start, yaw0, delta = self.centre.copy(), self.yaw, self.scene.to_world([dx, dy, dz])
        for p in range(1, periods + 1):
            f = p / periods
            self.d.mocap_pos[self.mocap] = start + f * delta
            self.d.mocap_quat[self.mocap] = self._quat(yaw0 + f * dtheta)
            for _ in range(self.substeps):
                self.mj.mj_step(self.m, self.d)
            self.periods += 1
            if pace:
                pace()
        self.centre, self.yaw = start + delta, yaw0 + dtheta
        report = self.coupler.couple()
        if not report.converged:
            raise RuntimeError(f"the FE block's step failed: {report.status}")

    def observe(self) -> list[float]:
        """The block's lower-face pose as MuJoCo shows it: (x, y, yaw) from rest in the
        block frame (m, m, rad), what a camera on the robot would report."""
        from pushplan.mujoco.scene import block_geom_pose

        lower, _, yaw = block_geom_pose(self.m, self.d, self.scene)
        x, y, _ = self.scene.to_fe(lower - self.scene.lower_centre)
        return [float(x), float(y), float(yaw - self.scene.yaw)]


def serve(root: Path) -> tuple[subprocess.Popen, str]:
    """``pushplan serve`` on a free loopback port, reading scenarios under ``root``."""
    proc = subprocess.Popen([sys.executable, "-m", "pushplan.cli", "serve", "--address", "127.0.0.1:0",
                             "--root", str(root)], stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if "listening on " not in line:
        proc.kill()
        raise RuntimeError(f"pushplan serve did not start: {line!r}")
    return proc, line.split("listening on ")[1].strip()


def _pacer(period: float, realtime: bool):
    """None, or a callable that holds each period to ``period`` s of wall clock after the
    previous one and counts the periods that overran (a late period starts the next at once)."""
    if not realtime:
        return None
    state = {"overruns": 0, "last": time.perf_counter()}

    def pace():
        due, now = state["last"] + period, time.perf_counter()
        if now > due:
            state["overruns"] += 1
            state["last"] = now
        else:
            time.sleep(due - now)
            state["last"] = due

    pace.state = state
    return pace


def control_loop(address: str, model: Path, truth: Path, periods: int, realtime: bool = False) -> dict:
    """Run the loop against the server at ``address``; returns what it did."""
    from pushplan.client import Client

    robot = Robot(truth)
    with Client(address) as client:
        session = client.open(scenario_path=str(model))  # both meshes: the first plan is verified
        pace = _pacer(robot.period, realtime)
        moves = len(session.info["press"]) + session.info["steps"]
        if periods % moves:
            raise ValueError(f"--periods {periods}: not a multiple of the {moves} moves (press and pushes)")
        each, calls, pushes = periods // moves, [], []
        for press in session.info["press"]:
            robot.move(press, each, pace)
        t0 = time.perf_counter()
        answer = session.plan()
        calls.append(time.perf_counter() - t0)
        executed = []
        for k in range(session.info["steps"]):
            dx, dy, dtheta = answer["commands"][0]
            robot.move((dx, dy, 0.0, dtheta), each, pace)
            executed.append([dx, dy, dtheta])
            observed = robot.observe()
            pushes.append({"push": k + 1, "command": [dx, dy, dtheta], "observed": observed,
                           "period": robot.periods, "time": float(robot.d.time)})
            print(f"push {k + 1}: period {robot.periods}, observed ({observed[0] * 1e3:.6f}, "
                  f"{observed[1] * 1e3:.6f}) mm", flush=True)
            if k + 1 < session.info["steps"]:
                t0 = time.perf_counter()
                answer = session.replan(executed, observed, force=robot.coupler.gripper_force.tolist(),
                                        time=float(robot.d.time), closed_loop=True)
                calls.append(time.perf_counter() - t0)
        session.close()
    return {"pose_units": ["m", "m", "rad"], "periods": robot.periods, "control_period_s": robot.period,
            "pushes": pushes,
            "final_pose": pushes[-1]["observed"], "call_wall_s": calls,
            "overruns": pace.state["overruns"] if pace else None}


def compare(done: dict, closed_loop_json: Path) -> float:
    """The distance (m) between the loop's final position and ``closed-loop``'s."""
    doc = json.loads(closed_loop_json.read_text())
    x, y, _ = doc["closed_loop"]["final_pose"]
    return math.hypot(done["final_pose"][0] - x, done["final_pose"][1] - y)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--address", help="a running pushplan serve (HOST:PORT; its --root must hold model.toml)")
    ap.add_argument("--model", type=Path, default=HERE / "model.toml")
    ap.add_argument("--truth", type=Path, default=HERE / "truth.toml", help="scenario TOML with a [mujoco] scene")
    ap.add_argument("--periods", type=int, default=200)
    ap.add_argument("--realtime", action="store_true", help="hold each period to the wall clock")
    ap.add_argument("--out", type=Path, help="write the loop's pushes and final pose as JSON")
    ap.add_argument("--compare", type=Path, help="closed_loop.json of `pushplan closed-loop` on the same case")
    ap.add_argument("--within", type=float, default=1e-9, help="m, for --compare")
    args = ap.parse_args(argv)
    server = None
    if args.address is None:
        server, args.address = serve(args.model.resolve().parent)
    try:
        t0 = time.perf_counter()
        done = control_loop(args.address, args.model.resolve(), args.truth, args.periods, args.realtime)
        done["wall_s"] = time.perf_counter() - t0
    finally:
        if server is not None:
            server.terminate()
            server.wait(60)
    x, y, yaw = done["final_pose"]
    print(f"{done['periods']} periods of {done['control_period_s']} s: final pose ({x * 1e3:.9f}, {y * 1e3:.9f}) mm, "
          f"yaw {math.degrees(yaw):.3g} deg; planner calls median {np.median(done['call_wall_s']) * 1e3:.0f} ms; "
          f"{done['wall_s']:.1f} s")
    status = 0
    if args.compare is not None:
        done["distance_to_closed_loop_m"] = gap = compare(done, args.compare)
        status = 0 if gap <= args.within else 1
        print(f"distance to pushplan closed-loop's final pose: {gap:.3g} m ({'within' if status == 0 else 'NOT within'} "
              f"{args.within:g} m)")
    if args.out is not None:
        args.out.write_text(json.dumps(done, indent=1) + "\n")
    return status


if __name__ == "__main__":
    sys.exit(main())
