"""Batch sweeps (issue 9): the same table from the local process pool and from Dask,
failed cases listed with their error, resume without redoing finished cases, the
heat map, and the steady twist against the elliptic friction law."""

import csv
import math
import shutil
from pathlib import Path

import pytest

from pushplan.cli import EXIT_SOLVER_FAILURE, main
from pushplan.config.sweep import apply_override, load_sweep, parse_sweep
from pushplan.resources import scenario_path
from pushplan.studies.sweep_run import CASE_RUNNERS, run_sweep

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
SAME_TABLE_RTOL = 1e-9  # pool vs Dask: same code, same inputs; only BLAS threading could move last bits
LAW_TOL_DEG = 0.05  # steady lag direction vs elliptic-law friction direction on a 2x2x1 block
WALL_TIME_COLUMNS = {"elapsed_s"}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MU_X = 0.3  # paper_case3
PUSH_DEG = 45.0  # paper_case3
BAD_PRESS = -0.012  # m: more than the block height, inverts elements

TINY_SWEEP = f"""
name = "tiny"
base = "{SCENARIOS / 'paper_case3.toml'}"
workers = 2
[set]
"block.elements" = [2, 2, 1]
"block.quadrature" = 2
"solver.local_method" = "newton"
[grid]
"friction.mu_y" = [0.3, 0.05]
"load[0].dz" = [-0.1e-3, {BAD_PRESS}]
[heatmap]
x = "load[0].dz"
y = "mu_ratio"
values = ["lag_angle_deg", "direction_deviation_deg"]
file = "tiny.png"
"""


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def elliptic_lag_angle_deg(mu_x, mu_y, push_deg):
    """Direction of the sliding friction force of the elliptic law (opposite to it,
    so along the lag) relative to the push direction: -grad of ||M v|| ~ M^2 v."""
    p = math.radians(push_deg)
    return math.degrees(math.atan2(mu_y**2 * math.sin(p), mu_x**2 * math.cos(p))) - push_deg


def file_times(root):
    return {p: p.stat().st_mtime_ns for p in Path(root).rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def pool_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    sweep_file = root / "tiny.toml"
    sweep_file.write_text(TINY_SWEEP)
    out, figure = root / "pool", root / "figure.png"
    rc = main(["sweep", str(sweep_file), "--out", str(out), "--figure", str(figure), "--quiet"])
    return sweep_file, out, figure, rc


def test_pool_table_lists_failures_and_matches_the_elliptic_law(pool_run):
    _, out, figure, rc = pool_run
    assert rc == EXIT_SOLVER_FAILURE  # some cases failed, the sweep went on
    rows = read_rows(out / "results.csv")
    assert len(rows) == 4
    for row in rows:
        bad = float(row["load[0].dz"]) == BAD_PRESS
        assert row["status"] == ("failed" if bad else "completed"), row
        assert (Path(out) / row["folder"] / "summary.json").is_file()
        if bad:
            assert "inverted" in row["error"] and row["steps_done"] == "0"
            assert row["lag_angle_deg"] == ""
            continue
        assert row["error"] == ""
        mu_y = float(row["friction.mu_y"])
        law = elliptic_lag_angle_deg(MU_X, mu_y, PUSH_DEG)
        assert float(row["lag_angle_deg"]) == pytest.approx(law, abs=LAW_TOL_DEG)
        assert row["steady_twist_deg"] == row["lag_angle_deg"]  # the old name, an alias for one release
        assert row["twist_deg"] == row["lower_direction_deviation_deg"] != row["lag_angle_deg"]
        assert float(row["mu_ratio"]) == pytest.approx(MU_X / mu_y)
    anisotropic = [r for r in rows if r["status"] == "completed" and float(r["friction.mu_y"]) < MU_X]
    assert float(anisotropic[0]["lag_angle_deg"]) < -40.0  # sheared nearly along the strong-friction axis
    heat = (out / "tiny.png").read_bytes()
    assert heat.startswith(PNG_MAGIC) and figure.read_bytes() == heat


def test_dask_cluster_gives_the_same_table(pool_run):
    from dask.distributed import LocalCluster
    sweep_file, out, _, _ = pool_run
    out_dask = out.parent / "dask"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None, silence_logs=40) as cluster:
        rc = main(["sweep", str(sweep_file), "--out", str(out_dask), "--scheduler", cluster.scheduler_address,
                   "--quiet"])
    assert rc == EXIT_SOLVER_FAILURE
    pool_rows, dask_rows = read_rows(out / "results.csv"), read_rows(out_dask / "results.csv")
    assert [list(r) for r in dask_rows] == [list(r) for r in pool_rows]
    for a, b in zip(pool_rows, dask_rows, strict=True):
        for key in a.keys() - WALL_TIME_COLUMNS:
            try:
                x, y = float(a[key]), float(b[key])
            except ValueError:
                assert a[key] == b[key], key
                continue
            assert y == pytest.approx(x, rel=SAME_TABLE_RTOL, abs=1e-300), key


def test_parquet_table_matches_csv(pool_run):
    pq = pytest.importorskip("pyarrow.parquet")  # optional output
    _, out, _, _ = pool_run
    table = pq.read_table(out / "results.parquet").to_pylist()
    rows = read_rows(out / "results.csv")
    assert [t["case"] for t in table] == [r["case"] for r in rows]
    assert [t["status"] for t in table] == [r["status"] for r in rows]


def test_resume_does_no_finished_case_again(pool_run, tmp_path):
    sweep_file, out, _, _ = pool_run
    work = tmp_path / "resume"
    shutil.copytree(out, work)
    sweep = load_sweep(sweep_file)
    before = file_times(work / "cases")
    result = run_sweep(sweep, work)
    assert result.ran == [] and len(result.skipped) == 4
    assert file_times(work / "cases") == before  # no case folder touched

    redo = next(r for r in read_rows(out / "results.csv") if r["status"] == "completed")
    (work / redo["folder"] / "case.json").unlink()
    result = run_sweep(sweep, work)
    assert result.ran == [redo["case"]]
    after = file_times(work / "cases")
    changed = {p for p in after if after[p] != before.get(p)}
    assert changed and all(redo["case"] in str(p) for p in changed)
    rerun_row = next(r for r in read_rows(work / "results.csv") if r["case"] == redo["case"])
    assert rerun_row["lag_angle_deg"] == redo["lag_angle_deg"]  # a rerun gives the same numbers

    result = run_sweep(sweep, work, rerun_failed=True)
    assert sorted(result.ran) == sorted(r["case"] for r in read_rows(out / "results.csv") if r["status"] == "failed")


def test_overrides_reach_the_intended_load_entries():
    base = {"load": [{"dz": -1e-4}, {"distance": 1e-4, "direction_deg": 0.0}, {"distance": 2e-4, "direction_deg": 0.0}]}
    apply_override(base, "load.direction_deg", 30.0)
    apply_override(base, "load[2].repeat", 3)
    apply_override(base, "friction.mu_y", 0.1)
    assert base == {
        "load": [{"dz": -1e-4}, {"distance": 1e-4, "direction_deg": 30.0},
                 {"distance": 2e-4, "direction_deg": 30.0, "repeat": 3}],
        "friction": {"mu_y": 0.1},
    }


def test_grid_expands_to_the_full_product(tmp_path):
    path = tmp_path / "grid.toml"
    path.write_text(TINY_SWEEP.replace('"friction.mu_y" = [0.3, 0.05]', '"friction.mu_y" = [0.3, 0.2, 0.05]'))
    sweep = load_sweep(path)
    pairs = [(c.params["friction.mu_y"], c.params["load[0].dz"]) for c in sweep.cases]
    assert pairs == [(m, d) for m in (0.3, 0.2, 0.05) for d in (-0.1e-3, BAD_PRESS)]
    assert len({c.case_id for c in sweep.cases}) == 6 and len({c.key for c in sweep.cases}) == 6
    assert all(c.scenario["load"][0]["dz"] == c.params["load[0].dz"] for c in sweep.cases)
    assert not (tmp_path / "out").exists()


PLAN_SWEEP = f"""
name = "plan_tiny"
base = "{SCENARIOS / 'plan_steel_case3.toml'}"
run = "plan"
workers = 2
[set]
"block.elements" = [4, 4, 2]
"block.quadrature" = 2
"plan.planning_elements" = [3, 3, 1]
"plan.tolerance" = 6.0e-6
[grid]
"friction.mu_y" = [0.05, 0.15]
"""


def test_plan_sweep_tabulates_verified_plan_errors(tmp_path):
    """``run = "plan"``: each case plans on its own friction and the table carries the
    FE-verified final errors of the plan and of the naive push."""
    sweep_file = tmp_path / "plan.toml"
    sweep_file.write_text(PLAN_SWEEP)
    out = tmp_path / "out"
    assert main(["sweep", str(sweep_file), "--out", str(out), "--quiet"]) == 0
    rows = read_rows(out / "results.csv")
    assert len(rows) == 2
    travel = math.hypot(0.9e-3, 0.9e-3)
    for row in rows:
        assert row["status"] == "completed", row
        plan_error, naive_error = float(row["plan_final_error"]), float(row["naive_final_error"])
        assert plan_error <= 6.0e-6 < naive_error, row
        assert naive_error > 0.01 * travel  # the anisotropy makes the straight push miss
    assert all((Path(p).parent / "plan.json").is_file() for p in (out / "cases").rglob("summary.json"))


def test_sweep_file_round_trips_through_to_dict():
    sweep = load_sweep(scenario_path("sweep_twist.toml"))
    assert len(sweep.cases) == 90
    assert sweep.to_dict()["base"] == "paper_case3.toml"
    assert parse_sweep(sweep.to_dict(), sweep.path) == sweep


def test_case_runners_name_importable_functions():
    from pushplan.config.sweep import RUNNERS
    from pushplan.studies.sweep_run import _runner

    from pushplan.cli import sweep as sweep_cli
    from pushplan.config.sweep import EXECUTORS

    assert tuple(CASE_RUNNERS) == RUNNERS
    assert sweep_cli.EXECUTORS == EXECUTORS  # repeated there for a cheap --help
    assert all(callable(_runner(name)) for name in RUNNERS)


def test_thread_variables_are_set_in_the_workers_only(tmp_path, monkeypatch):
    """The case processes run single-threaded BLAS; the caller's environment is not touched."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    from threadpoolctl import threadpool_info

    from pushplan.studies.sweep_pool import THREAD_VARIABLES, single_threaded, worker_environment

    for var in THREAD_VARIABLES:
        monkeypatch.delenv(var, raising=False)
    before = dict(os.environ)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=single_threaded,
                             initargs=(worker_environment(),)) as pool:
        assert [pool.submit(os.getenv, var).result() for var in THREAD_VARIABLES] == ["1"] * len(THREAD_VARIABLES)
        blas = [p for p in pool.submit(threadpool_info).result() if p["user_api"] == "blas"]
        assert blas and all(p["num_threads"] == 1 for p in blas)  # also the BLAS loaded before the initializer
    path = tmp_path / "one.toml"
    path.write_text(TINY_SWEEP.replace(f'"load[0].dz" = [-0.1e-3, {BAD_PRESS}]', '"load[0].dz" = [-0.1e-3]'))
    result = run_sweep(load_sweep(path), tmp_path / "out")
    assert result.all_completed and len(result.rows) == 2
    assert dict(os.environ) == before
