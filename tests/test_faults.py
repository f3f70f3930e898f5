"""Faults (issue 23): ``kill -9`` at spread-out points of ``simulate`` and ``sweep``
leaves the previous complete output or the new complete one, never a mix, and no
process of the run outlives it by more than 5 s; a full disk is exit 1 with one line
and the previous output intact; a second run into a locked ``--out`` refuses; a
silent scheduler fails within 30 s; a killed pool worker is replaced and its case
rerun; SIGINT stops a sweep with exit 130 and a rerun resumes it."""

import hashlib
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "FE_CONTACT_DENSE_THREADS": "1",
       "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
SURVIVAL_S = 5.0  # the issue: no process of the run survives its parent by more than 5 s
KILL_POINTS = 10

SCENARIO = """
name = "faults"
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
distance = 0.02e-3
direction_deg = 45.0
repeat = {repeat}
[solver]
local_method = "newton"
"""
SWEEP = """
base = "base.toml"
workers = 2
[grid]
"friction.mu_y" = [0.1, 0.15, 0.2, 0.25]
"""


def cli(*args, **kw):
    return [sys.executable, "-m", "pushplan.cli", *map(str, args)]


def snapshot(folder: Path) -> dict:
    """Relative path -> sha256 of every file under ``folder`` (hidden ones included)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path, name: str) -> list[str]:
    """Siblings of a transaction (``.NAME.*``) and temporaries inside ``parent/name``."""
    found = [p.name for p in parent.iterdir() if p.name.startswith(f".{name}.")]
    if (parent / name).is_dir():
        found += [p.name for p in (parent / name).rglob(".*.tmp")]
    return found


def pgroup_alive(pgid: int) -> bool:
    """A process of group ``pgid`` still runs (zombies, which only wait for their
    parent to reap them, do not count)."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def kill_and_wait(proc, delay, timeout: float = 60.0) -> float:
    """``kill -9`` the run after ``delay`` s, or as soon as ``delay()`` is true (or
    let it end); seconds until no process of its group (the run started in its own
    session) is left."""
    if callable(delay):
        t0 = time.monotonic()
        while not delay() and proc.poll() is None and time.monotonic() - t0 < timeout:
            time.sleep(0.002)
    else:
        time.sleep(delay)
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    t0 = time.monotonic()
    while pgroup_alive(proc.pid) and time.monotonic() - t0 < 30:
        time.sleep(0.05)
    return time.monotonic() - t0


def check_simulate_output(out: Path, steps: int) -> None:
    """A complete new output of the long run: completed summary, fields and recording of ``steps`` steps."""
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and len(summary["steps"]) == steps
    with np.load(out / "fields.npz") as f:
        assert f["displacement"].shape[0] == steps
    assert (out / "recording.rrd").stat().st_size > 0


@pytest.fixture(scope="module")
def simulate_setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kill_simulate")
    (tmp / "old.toml").write_text(SCENARIO.format(repeat=1))
    (tmp / "new.toml").write_text(SCENARIO.format(repeat=40))
    good = tmp / "good"
    subprocess.run(cli("simulate", tmp / "old.toml", "--out", good, "--quiet"), env=ENV, check=True,
                   capture_output=True, timeout=120)
    t0 = time.monotonic()
    full = tmp / "full"
    subprocess.run(cli("simulate", tmp / "new.toml", "--out", full, "--quiet"), env=ENV, check=True,
                   capture_output=True, timeout=120)
    return tmp, good, time.monotonic() - t0


def test_kill_9_during_simulate_leaves_the_old_or_the_new_output(simulate_setup):
    tmp, good, duration = simulate_setup
    old = snapshot(good)
    rng = random.Random(23)
    # spread over the whole life of the process: start-up, steps, the final writes and the
    # swap; and three points aimed at the transaction: its folder created, steps in it,
    # its last file written (the swap follows)
    delays = sorted(rng.uniform(0.1, 1.1 * duration) for _ in range(KILL_POINTS))

    def staged(parent, name=None):
        def ready():
            found = list(parent.glob(".out.*.partial")) + list(parent.glob(".out.*.ready"))
            return bool(found) and (name is None or any((f / name).exists() for f in found))
        return ready

    outcomes = []
    for i, delay in enumerate([*delays, "partial", "summary.json", "fields.npz"]):
        parent = tmp / f"k{i}"
        parent.mkdir()
        out = parent / "out"
        if isinstance(delay, str):
            delay = staged(parent, None if delay == "partial" else delay)
        shutil.copytree(good, out)
        proc = subprocess.Popen(cli("simulate", tmp / "new.toml", "--out", out, "--quiet"), env=ENV,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        survived = kill_and_wait(proc, delay)
        assert survived <= SURVIVAL_S
        if snapshot(out) == old:
            outcomes.append("old")
        else:  # not the old output: then all of the new one, nothing of the old
            check_simulate_output(out, 41)
            outcomes.append("new")
    print(f"kill -9 of simulate at {[round(d, 2) for d in delays]} s and at the transaction's stages: {outcomes}")
    assert len(outcomes) >= KILL_POINTS + 3 and "old" in outcomes
    # the next run repairs and removes what a killed one left (the lock died with it)
    dirty = [p for p in sorted(tmp.glob("k*")) if leftovers(p, "out")][:2] or [tmp / "k0"]
    for parent in dirty:
        rerun = cli("simulate", tmp / "old.toml", "--out", parent / "out", "--quiet", "--no-recording")
        assert subprocess.run(rerun, env=ENV, capture_output=True, timeout=120).returncode == 0
        assert leftovers(parent, "out") == []
        assert not (parent / "out" / "recording.rrd").exists()  # a run without a recording keeps no old one


def case_state(case_dir: Path, new_key: str) -> str:
    """'new' (complete, this sweep's key), 'old' (complete, the previous key)."""
    record = json.loads((case_dir / "case.json").read_text())
    summary = json.loads((case_dir / "summary.json").read_text())
    assert record["status"] == summary["status"] == "completed"
    with np.load(case_dir / "fields.npz") as f:
        assert f["displacement"].shape[0] == len(summary["steps"])
    return "new" if record["key"] == new_key else "old"


def test_kill_9_during_a_sweep_leaves_complete_case_folders_and_no_worker(tmp_path):
    (tmp_path / "base.toml").write_text(SCENARIO.format(repeat=1))
    (tmp_path / "sweep.toml").write_text(SWEEP)
    good = tmp_path / "good"
    subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", good, "--quiet"), env=ENV, check=True,
                   capture_output=True, timeout=300)
    old_cases = {p.name: snapshot(p) for p in (good / "cases").iterdir()}
    (tmp_path / "base.toml").write_text(SCENARIO.format(repeat=25))  # a new key for every case
    t0 = time.monotonic()
    subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", tmp_path / "full", "--quiet"), env=ENV,
                   check=True, capture_output=True, timeout=300)
    duration = time.monotonic() - t0
    new_keys = {p.name: json.loads((p / "case.json").read_text())["key"]
                for p in (tmp_path / "full" / "cases").iterdir()}
    rng = random.Random(2300)
    delays = sorted(rng.uniform(0.2, duration) for _ in range(KILL_POINTS))
    seen, states = set(), []
    for i, delay in enumerate([*delays, "first case"]):
        out = tmp_path / f"k{i}"
        shutil.copytree(good, out)
        if delay == "first case":  # as soon as one case folder of the new sweep is in place

            def delay(out=out):
                return any(json.loads((p / "case.json").read_text())["key"] == new_keys[p.name]
                           for p in (out / "cases").iterdir() if (p / "case.json").exists() and p.name in new_keys)
        proc = subprocess.Popen(cli("sweep", tmp_path / "sweep.toml", "--out", out, "--quiet"), env=ENV,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        assert kill_and_wait(proc, delay) <= SURVIVAL_S  # the pool workers die with the sweep
        for case_dir in (out / "cases").iterdir():  # a killed case's staging sibling may stay, never a mix
            if case_dir.name.startswith("."):
                assert case_dir.name.endswith((".partial", ".ready", ".old")), case_dir.name
        for name, old in old_cases.items():
            state = case_state(out / "cases" / name, new_keys[name])
            if state == "old":
                assert snapshot(out / "cases" / name) == old
            seen.add(state)
        states.append(sorted(case_state(out / "cases" / n, new_keys[n]) for n in old_cases))
    print(f"kill -9 of sweep at {[round(d, 2) for d in delays]} s and after its first case: case folders {states}")
    assert "old" in seen
    # the next run into a killed sweep's folder removes what the kills left and completes it
    last = tmp_path / f"k{len(delays)}"
    subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", last, "--quiet"), env=ENV, check=True,
                   capture_output=True, timeout=300)
    assert not [p.name for p in (last / "cases").iterdir() if p.name.startswith(".")]
    assert {case_state(last / "cases" / n, new_keys[n]) for n in old_cases} == {"new"}


def _flock_held(path) -> bool:
    """Whether another process holds ``flock`` on ``path`` (tried without blocking)."""
    import fcntl

    fd = os.open(path, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing drops a lock this process took
    return False


def test_second_run_into_a_locked_out_refuses(tmp_path):
    (tmp_path / "s.toml").write_text(SCENARIO.format(repeat=40))
    out = tmp_path / "out"
    first = subprocess.Popen(cli("simulate", tmp_path / "s.toml", "--out", out, "--quiet"), env=ENV,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lock = tmp_path / ".out.lock"
    t0 = time.monotonic()
    while not lock.exists() and time.monotonic() - t0 < 60:
        time.sleep(0.02)
    # the first run stopped (SIGSTOP) once it holds the folder's lock, so the second meets it
    # however fast the first would finish
    while True:
        first.send_signal(signal.SIGSTOP)
        if _flock_held(lock):
            break
        first.send_signal(signal.SIGCONT)
        assert first.poll() is None and time.monotonic() - t0 < 60, "the first run never held its lock"
        time.sleep(0.01)
    try:
        second = subprocess.run(cli("simulate", tmp_path / "s.toml", "--out", out, "--quiet"), env=ENV,
                                capture_output=True, text=True, timeout=120)
    finally:
        first.send_signal(signal.SIGCONT)
    assert first.wait(timeout=120) == 0, first.stderr.read()
    assert second.returncode == 2
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and "in use by another pushplan run" in lines[0] and str(out) in lines[0]
    check_simulate_output(out, 41)
    assert leftovers(tmp_path, "out") == []


# ---- full disk -------------------------------------------------------------------

FULL_DISK_SCRIPT = r"""
set -e
mount -t tmpfs -o size=256k tmpfs "$DISK"
cd "$WORK"
python -m pushplan.cli simulate old.toml --out "$DISK/out" --quiet --no-recording > /dev/null
(cd "$DISK/out" && sha256sum * > "$WORK/before.txt")
dd if=/dev/zero of="$DISK/filler" bs=1k count=10000 2>/dev/null || true
rm -f "$DISK/filler"; dd if=/dev/zero of="$DISK/filler" bs=1k count=$(( $(df -k "$DISK" | awk 'NR==2 {print $4}') - 40 )) 2>/dev/null || true
set +e
timeout 120 python -m pushplan.cli simulate new.toml --out "$DISK/out" --quiet --no-recording > "$WORK/stdout.txt" 2> "$WORK/stderr.txt"
echo $? > "$WORK/rc.txt"
(cd "$DISK/out" && sha256sum * > "$WORK/after.txt")
ls -a "$DISK" > "$WORK/listing.txt"
"""


def test_full_disk_exits_1_with_one_line_and_keeps_the_previous_output(tmp_path):
    (tmp_path / "old.toml").write_text(SCENARIO.format(repeat=1))
    (tmp_path / "new.toml").write_text(SCENARIO.format(repeat=40))
    disk = tmp_path / "disk"
    disk.mkdir()
    env = {**ENV, "DISK": str(disk), "WORK": str(tmp_path),
           "PATH": f"{Path(sys.executable).parent}:{ENV['PATH']}"}
    unshare = shutil.which("unshare")
    proc = subprocess.run([unshare, "--user", "--map-root-user", "--mount", "bash", "-c", FULL_DISK_SCRIPT],
                          env=env, capture_output=True, text=True, timeout=300) if unshare else None
    if proc is not None and (tmp_path / "rc.txt").exists():
        rc = int((tmp_path / "rc.txt").read_text())
        err = (tmp_path / "stderr.txt").read_text().strip().splitlines()
        assert rc == 1, (err, proc.stderr)
        assert (tmp_path / "after.txt").read_text() == (tmp_path / "before.txt").read_text()
        assert [n for n in (tmp_path / "listing.txt").read_text().split() if n.startswith(".out.")] == []
    else:  # no tmpfs here: the same failure simulated (ENOSPC from the writer of fields.npz)
        err = simulated_enospc(tmp_path)
    assert len(err) == 1 and err[0].startswith("pushplan: error: cannot write ") and "no space left" in err[0]


def simulated_enospc(tmp_path) -> list[str]:
    code = ("import errno, sys\n"
            "import pushplan.outputs.atomic as a\n"
            "real = a.atomic_write_bytes\n"
            "def full(path, data):\n"
            "    if str(path).endswith('fields.npz'):\n"
            "        raise OSError(errno.ENOSPC, 'No space left on device', str(path))\n"
            "    return real(path, data)\n"
            "a.atomic_write_bytes = full\n"
            "from pushplan.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    out = tmp_path / "out"
    subprocess.run(cli("simulate", tmp_path / "old.toml", "--out", out, "--quiet"), env=ENV, check=True,
                   capture_output=True, timeout=120)
    before = snapshot(out)
    proc = subprocess.run([sys.executable, "-c", code, "simulate", tmp_path / "new.toml", "--out", out,
                           "--quiet", "--no-recording"], env=ENV, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert snapshot(out) == before and leftovers(tmp_path, "out") == []
    return proc.stderr.strip().splitlines()


# ---- sweeps ---------------------------------------------------------------------------


def test_a_silent_scheduler_fails_within_30_s_with_one_line(tmp_path):
    (tmp_path / "base.toml").write_text(SCENARIO.format(repeat=1))
    (tmp_path / "sweep.toml").write_text(SWEEP)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)  # accepts (the kernel completes the handshake) and never answers
    port = listener.getsockname()[1]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", tmp_path / "out", "--scheduler",
                                  f"tcp://127.0.0.1:{port}"), env=ENV, capture_output=True, text=True, timeout=60)
    finally:
        listener.close()
    assert time.monotonic() - t0 < 30
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--scheduler" in lines[0] and str(port) in lines[0], proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_peer_answering_http_is_not_a_dask_scheduler(tmp_path):
    (tmp_path / "base.toml").write_text(SCENARIO.format(repeat=1))
    (tmp_path / "sweep.toml").write_text(SWEEP)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    port = listener.getsockname()[1]

    def serve():
        with listener:
            conn, _ = listener.accept()
            with conn:  # a server that speaks first, not the Dask protocol
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                time.sleep(2)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    proc = subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", tmp_path / "out", "--scheduler",
                              f"127.0.0.1:{port}"), env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "does not speak the Dask protocol" in lines[0], proc.stderr


def test_a_killed_worker_is_replaced_and_its_case_rerun(tmp_path):
    """Deterministic (it was timed, and killed a worker that could be gone already:
    ProcessLookupError): case 1 kills its own worker (SIGKILL) on its first attempt; the
    pool is rebuilt, case 1 reruns and completes, the others complete, each recorded
    once.  A case that kills its worker on every attempt is an error after MAX_ATTEMPTS."""
    from pushplan.studies.sweep_pool import MAX_ATTEMPTS, run_local
    from tiny_inputs import killing_case

    outcomes = {}

    def on_result(task, outcome):
        assert task["id"] not in outcomes  # each case recorded once
        outcomes[task["id"]] = outcome

    run_local(killing_case, [{"id": i, "dir": str(tmp_path), "kill": int(i == 1)} for i in range(4)], 2, on_result)
    assert sorted(outcomes) == [0, 1, 2, 3]
    assert outcomes[1]["id"] == 1 and outcomes[1]["attempt"] == 2  # rerun after its worker was killed
    assert all(outcomes[i]["id"] == i for i in (0, 2, 3))
    outcomes.clear()
    run_local(killing_case, [{"id": 9, "dir": str(tmp_path), "kill": 99}], 1, on_result)
    assert f"a worker died on each of {MAX_ATTEMPTS} attempts" in str(outcomes[9])
    assert len(list(tmp_path.glob("case9.attempt*"))) == MAX_ATTEMPTS


def test_sigint_stops_a_sweep_with_130_and_a_rerun_resumes(tmp_path):
    (tmp_path / "base.toml").write_text(SCENARIO.format(repeat=40))
    (tmp_path / "sweep.toml").write_text(SWEEP.replace("workers = 2", "workers = 1"))
    out = tmp_path / "out"
    proc = subprocess.Popen(cli("sweep", tmp_path / "sweep.toml", "--out", out, "--quiet"), env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    t0 = time.monotonic()
    while not list(out.glob("cases/*/case.json")) and time.monotonic() - t0 < 120:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in a terminal: the whole group
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert stderr.strip().splitlines() == ["pushplan: interrupted, rerun to resume"]
    t1 = time.monotonic()
    while pgroup_alive(proc.pid) and time.monotonic() - t1 < 30:
        time.sleep(0.05)
    assert time.monotonic() - t1 <= SURVIVAL_S
    done = len(list(out.glob("cases/*/case.json")))
    assert 1 <= done < 4
    rerun = subprocess.run(cli("sweep", tmp_path / "sweep.toml", "--out", out), env=ENV,
                           capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert f"({4 - done} run, {done} already finished)" in rerun.stdout
