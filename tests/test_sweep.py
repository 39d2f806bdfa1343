"""`aslam sweep` on real Dask clusters (a LocalCluster, and a scheduler + worker started as processes).

The recordings are tiny renders (64×48, paper route, 2 laps) so that a sweep takes seconds; the
corrupt one is that recording with garbage bytes written over its middle: it opens as a recording,
so the sweep plans it, and its task fails on the damage.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import psutil
import pyarrow.csv
import pyarrow.parquet
import pytest
from conftest import one_error_line, random_frames, write_recording
from distributed import Client
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.app.sweep import (
    VARYING_COLUMNS,
    Objective,
    TaskResult,
    arrow_table,
    distinct_names,
    open_client,
    pareto_front,
    plan_tasks,
    render_path,
    render_text,
    resolve_objectives,
    rows,
    run_sweep,
    run_task,
    table_bytes,
)
from aslam.app.sweep_file import RENDER_KEYS, read_sweep_file
from aslam.cli.app import main
from aslam.core.errors import ConfigError, InputError
from aslam.recorder.config import CameraSpec, NoiseParams, RecordConfig
from aslam.recorder.record import record

FIGURES = ["keyframes", "loop_closure.precision", "loop_closure.recall", "error.best.x_m.mean"]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("recordings")
    record(RecordConfig(route="paper", laps=2, seed=0, camera=CameraSpec(64, 48)), folder / "good.mcap")
    damaged = bytearray((folder / "good.mcap").read_bytes())
    middle = len(damaged) // 2
    damaged[middle : middle + 4096] = bytes(range(256)) * 16
    (folder / "corrupt.mcap").write_bytes(bytes(damaged))
    return folder


def _write_sweep(folder: Path) -> Path:
    """3 tasks: a recording file, a corrupt file, and a recording rendered by the sweep itself."""
    path = folder / "sweep.toml"
    path.write_text(
        f"""
figures = {json.dumps(FIGURES)}

[recordings]
paths = ["good.mcap", "corrupt.mcap"]

[[render]]
route = "paper"
seeds = [1]
laps = 2
size = "64x48"

[grid]
beta = 3.0

[score]
radius_m = 0.5
"""
    )
    return path


@pytest.fixture(scope="module")
def local_run(recordings, tmp_path_factory):
    """The sweep on a local cluster of 2 worker processes, through the command line."""
    results = tmp_path_factory.mktemp("local")
    code = main(["sweep", str(_write_sweep(recordings)), "-o", str(results), "--workers", "2", "-q"])
    return code, results


def _rows(results: Path) -> list[dict]:
    return pyarrow.parquet.read_table(results / "results.parquet").to_pylist()


def test_local_cluster_runs_three_tasks_one_failing_on_a_corrupt_recording(local_run, recordings):
    code, results = local_run
    assert code == 3  # some tasks failed
    rows = _rows(results)
    assert [row["task"] for row in rows] == [0, 1, 2]
    good, corrupt, rendered = rows
    for row in (good, rendered):
        assert row["status"] == "ok" and row["error"] == ""
        assert row["keyframes"] > 20
        assert 0 <= row["loop_closure.precision"] <= 1 and 0 < row["loop_closure.recall"] <= 1
        assert row["error.best.x_m.mean"] is not None
        assert row["estimate_wall_s"] > 0 and row["keyframes_per_second"] > 0
        assert row["worker"].startswith("tcp://")
        assert row["param.beta"] == 3.0
    assert good["recording"] == str(recordings / "good.mcap")
    assert rendered["render"].startswith("route=paper seed=1")
    assert Path(rendered["recording"]).is_file()
    assert corrupt["status"] == "error"
    assert str(recordings / "corrupt.mcap") in corrupt["error"]
    assert "corrupt MCAP data" in corrupt["error"]
    assert corrupt["loop_closure.precision"] is None and corrupt["keyframes"] is None
    csv = pyarrow.csv.read_csv(results / "results.csv")
    assert csv.num_rows == 3 and csv.column("status").to_pylist() == ["ok", "error", "ok"]
    assert not list(results.glob(".*partial*"))


def _figures(rows: list[dict]) -> list[dict]:
    """What must not depend on where or how fast a task ran."""
    drop = {*VARYING_COLUMNS, "recording"}  # a render's path is under its results folder
    return [{k: v for k, v in row.items() if k not in drop} for row in rows]


def _finished_sweep(recordings: Path) -> Path:
    """The local run's sweep without its corrupt recording: every task is done in its results."""
    path = recordings / "finished.toml"
    path.write_text(
        _write_sweep(recordings).read_text().replace('"good.mcap", "corrupt.mcap"', '"good.mcap"')
    )
    return path


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*")}


@pytest.fixture
def read_only_results(local_run, tmp_path):
    """A copy of the local run's results folder that cannot be written (a colleague's, shared): for
    root (whom mode bits do not stop) bind-mounted read-only, skipped where mounting is refused;
    for anyone else ``chmod -R a-w``."""
    copy = tmp_path / "copy"
    shutil.copytree(local_run[1], copy)
    if os.geteuid() != 0:
        for path in (copy, *copy.rglob("*")):
            path.chmod(path.stat().st_mode & ~0o222)
        try:
            yield copy, "Permission denied"
        finally:
            for path in (copy, *copy.rglob("*")):
                path.chmod(path.stat().st_mode | 0o200)
        return
    mounted = tmp_path / "read-only"
    mounted.mkdir()
    bound = subprocess.run(["mount", "--bind", str(copy), str(mounted)], capture_output=True)
    if bound.returncode != 0:
        pytest.skip("cannot bind-mount here")
    try:
        remounted = subprocess.run(["mount", "-o", "remount,bind,ro", str(mounted)], capture_output=True)
        if remounted.returncode != 0:
            pytest.skip("cannot remount read-only here")
        yield mounted, "Read-only file system"
    finally:
        subprocess.run(["umount", str(mounted)], check=False)


def test_a_pareto_set_that_cannot_be_printed_fails_before_the_wrote_line(local_run, recordings, tmp_path):
    """stdout on a full disk: the command fails (exit 2) and says only that; the line saying what
    it wrote came before the Pareto set and stood over the failure."""
    folder = tmp_path / "copy"
    shutil.copytree(local_run[1], folder)
    aslam = Path(sys.executable).with_name("aslam")
    command = [str(aslam), "sweep", str(_finished_sweep(recordings)), "-o", str(folder)]
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [*command, "--pareto", "precision"], stdout=full, stderr=subprocess.PIPE, text=True
        )
    assert done.returncode == 2
    assert "wrote " not in done.stderr and "kept " not in done.stderr
    assert done.stderr.endswith("aslam: error: stdout: No space left on device\n")


def test_a_finished_sweep_in_a_read_only_folder_shows_its_results(read_only_results, recordings, capsys):
    """Nothing to do: the Pareto set and the rows are read and printed, nothing written (tables out
    of date are left, with a warning). Work to do: one line and exit 2 before any task runs."""
    folder, problem = read_only_results
    before = _files(folder)
    args = ["sweep", str(_finished_sweep(recordings)), "-o", str(folder), "--pareto", "precision,recall"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "Pareto set:" in captured.out and "good.mcap" in captured.out
    assert "2 tasks, 2 already done, 0 to run" in captured.err
    # the folder's tables hold the corrupt recording's row too: out of date, and left so
    assert (
        f"aslam: warning: {folder}: {problem}; results.parquet and results.csv left as they were"
        in captured.err
    )
    assert f"kept {folder / 'results.parquet'} and results.csv" in captured.err
    assert _files(folder) == before
    # the corrupt recording's failed task is to be tried again: that needs writing
    assert main(["sweep", str(_write_sweep(recordings)), "-o", str(folder), "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"aslam: error: {folder}: {problem}; the results folder must be writable for the 1 task to run\n"
    )
    # a dry run says so too, with the plan
    assert main(["sweep", str(_write_sweep(recordings)), "-o", str(folder), "--dry-run", "--json", "-"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out)["cannot_write"] == f"{folder}: {problem}"
    assert captured.err == err
    assert _files(folder) == before


def test_a_rerun_with_nothing_to_do_writes_nothing(local_run, recordings, tmp_path, capsys):
    """The tables are rewritten only when they would change (here: once, without the corrupt
    recording's row); then a re-run, --pareto or not, leaves every file of the folder as it was."""
    folder = tmp_path / "copy"
    shutil.copytree(local_run[1], folder)
    sweep = str(_finished_sweep(recordings))
    assert main(["sweep", sweep, "-o", str(folder), "-q"]) == 0
    assert [row["status"] for row in _rows(folder)] == ["ok", "ok"]
    before = _files(folder)
    assert main(["sweep", sweep, "-o", str(folder), "--pareto", "precision,recall"]) == 0
    assert "kept" in capsys.readouterr().err
    assert _files(folder) == before


def test_a_dry_run_lists_what_would_run_without_a_cluster_or_a_write(local_run, recordings, tmp_path, capsys):
    """--dry-run checks the file and the options, counts the tasks done in the results folder and
    lists those to run; it contacts no scheduler (one where nothing listens is never asked) and
    writes nothing, not even a new results folder. --json - is the same plan for a program."""
    sweep = str(_write_sweep(recordings))
    folder = tmp_path / "copy"
    shutil.copytree(local_run[1], folder)
    before = _files(folder)
    nowhere = ["--scheduler", "tcp://127.0.0.1:1"]  # a run would stop here: cannot reach it
    assert main(["sweep", sweep, "-o", str(folder), "--dry-run", *nowhere]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "3 tasks, 2 already done, 1 to run"
    assert "To run: 1 of 3 tasks" in out and "corrupt.mcap" in out and "good.mcap" not in out
    assert main(["sweep", sweep, "-o", str(folder), "--dry-run", "--json", "-", *nowhere]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert {k: plan[k] for k in ("tasks", "done", "to_run", "shared", "renders_due", "cannot_write")} == {
        "tasks": 3,
        "done": 2,
        "to_run": 1,
        "shared": 0,
        "renders_due": 0,
        "cannot_write": None,
    }
    assert [row["state"] for row in plan["rows"]] == ["done", "to run", "done"]
    assert [row["key"] for row in plan["rows"]] == [row["key"] for row in _rows(folder)]
    assert plan["rows"][1]["recording"] == str(recordings / "corrupt.mcap")
    assert plan["rows"][1]["parameters"] == {"beta": 3.0}
    assert _files(folder) == before
    fresh = tmp_path / "fresh"
    assert main(["sweep", sweep, "-o", str(fresh), "--dry-run", "--force", "--json", "-"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert (plan["done"], plan["to_run"], plan["renders_due"]) == (0, 3, 1)
    assert not fresh.exists()
    assert main(["sweep", sweep, "-o", str(fresh), "--json", "-"]) == 2
    assert capsys.readouterr().err == "aslam: error: --json writes the plan of --dry-run; give both\n"
    assert main(["sweep", sweep, "-o", str(fresh), "--dry-run", "--workers", "0"]) == 2
    assert "--workers must be at least 1" in capsys.readouterr().err


def test_a_cluster_started_separately_gives_the_same_rows(local_run, recordings, tmp_path):
    """`dask scheduler` and `dask worker` as real processes; the sweep joins with --scheduler-file,
    as a batch job's script does (the address itself, --scheduler, in the tests below)."""
    dask = Path(sys.executable).with_name("dask")
    scheduler_file = tmp_path / "scheduler.json"
    processes = [
        subprocess.Popen(
            [
                str(dask),
                "scheduler",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(scheduler_file),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        processes.append(
            subprocess.Popen(
                [str(dask), "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        results = tmp_path / "results"
        sweep = str(_write_sweep(recordings))
        code = main(["sweep", sweep, "-o", str(results), "--scheduler-file", str(scheduler_file), "-q"])
        with Client(address, timeout=30) as client:  # the workers of *this* scheduler, none other
            cluster_workers = set(client.scheduler_info()["workers"])
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in reversed(processes):
            process.wait(timeout=30)
    assert code == 3
    rows = _rows(results)
    ran_on = {row["worker"] for row in rows if row["status"] == "ok"}
    assert ran_on and ran_on <= cluster_workers
    assert _figures(rows) == _figures(_rows(local_run[1]))


#: A parameter set a grid may well explore that computes for a minute on the 2-lap 64×48 recording
#: (3,000 hypotheses over 16,384-long histograms; measured 66 s) instead of a tenth of a second.
SLOW_GRID = """
[[grid]]
observation_model = "histogram"
cells_x = 32
cells_y = 32
max_hypotheses = 10000
prune_ratio = 1e-12
place_radius_m = 10.0
gate_sigma = 100.0
"""


def test_a_task_over_the_timeout_is_stopped_and_its_worker_replaced(recordings, tmp_path, capsys):
    """--task-timeout: the slow task's row fails saying so, its worker process is gone (restarted by
    its nanny, not left computing), and the next task runs on the new worker; exit 3. A failed row
    has no estimate file: a task that finished while its worker closed (the nanny waits 4 s) had
    written one; planted here where the slow task writes, it is removed."""
    sweep = tmp_path / "s.toml"
    sweep.write_text(
        f'figures = ["keyframes"]\n[recordings]\npaths = ["{recordings / "good.mcap"}"]\n'
        + SLOW_GRID
        + "[[grid]]\nbeta = 3.0\n"
    )
    results = tmp_path / "results"
    assert main(["sweep", str(sweep), "-o", str(results), "--task-timeout", "0", "--dry-run"]) == 2
    assert "--task-timeout must be a number of seconds above 0, got 0" in capsys.readouterr().err
    slow_task, _ = plan_tasks(read_sweep_file(sweep), results)
    slow_task.estimate_path.parent.mkdir(parents=True)
    slow_task.estimate_path.write_bytes(b"finished while its worker closed")
    client = open_client(workers=1, scheduler=None)  # one worker: the next task needs it freed
    try:
        (before,) = client.run(os.getpid).values()
        started = time.monotonic()
        cluster = ["--scheduler", client.scheduler.address, "--task-timeout", "3", "-q"]
        code = main(["sweep", str(sweep), "-o", str(results), *cluster])
        elapsed = time.monotonic() - started
        (after,) = client.run(os.getpid).values()
        slow_worker_state = psutil.Process(before).status() if psutil.pid_exists(before) else "gone"
    finally:
        client.close()
        client.cluster.close()
    assert code == 3
    slow, fast = _rows(results)
    assert slow["status"] == "error" and slow["keyframes"] is None
    assert slow["error"] == (
        "timed out: still computing after 3 s (--task-timeout); stopped by restarting its worker"
    )
    assert fast["status"] == "ok" and fast["keyframes"] > 20
    assert fast["worker"] != slow["worker"] and after != before
    assert slow_worker_state in ("gone", psutil.STATUS_ZOMBIE)
    assert not slow_task.estimate_path.exists()
    assert elapsed < 60  # the slow task alone computes for a minute
    assert main(["sweep", str(sweep), "-o", str(results), "--dry-run"]) == 0  # a failed task: tried again
    assert capsys.readouterr().out.splitlines()[0] == "2 tasks, 1 already done, 1 to run"


def test_a_task_over_the_timeout_on_a_worker_without_a_nanny_fails_and_its_worker_computes_on(
    recordings, tmp_path
):
    """`dask worker --no-nanny`: Dask cannot restart a worker without a nanny (its client refuses
    with a ValueError, which the row quoted). The row fails saying so and that the worker computes
    on, and it does: the process is still there, busy, after the sweep ended."""
    sweep = tmp_path / "s.toml"
    sweep.write_text(
        f'figures = ["keyframes"]\n[recordings]\npaths = ["{recordings / "good.mcap"}"]\n' + SLOW_GRID
    )
    results = tmp_path / "results"
    scheduler, address = _scheduler(tmp_path)
    dask = Path(sys.executable).with_name("dask")
    worker = subprocess.Popen(
        [str(dask), "worker", address, "--no-nanny", "--nthreads", "1", "--no-dashboard"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        with Client(address, timeout=30) as client:
            client.wait_for_workers(1, timeout=60)
        code = main(
            ["sweep", str(sweep), "-o", str(results), "--scheduler", address, "--task-timeout", "1", "-q"]
        )
        process = psutil.Process(worker.pid)  # no nanny: the worker is the `dask worker` process
        before = process.cpu_times().user
        time.sleep(1.0)
        busy_s = process.cpu_times().user - before
    finally:
        worker.kill()  # SIGTERM waits for the task it computes: a minute
        worker.wait(timeout=30)
        scheduler.terminate()
        scheduler.wait(timeout=30)
    assert code == 3
    (row,) = _rows(results)
    assert row["error"] == (
        "timed out: still computing after 1 s (--task-timeout); its worker has no nanny to restart "
        "it (dask worker --no-nanny) and computes on until the task ends"
    )
    assert busy_s > 0.1


def test_overdue_tasks_on_a_worker_with_a_nanny_and_one_without_each_get_their_own_text(tmp_path):
    """A cluster of your own mixing `dask worker` and `dask worker --no-nanny`, a task over the
    limit on each at the same check: Dask refused the restart of both for the one without a nanny,
    so the worker that had one computed on, and its row named the other worker's ValueError."""
    from aslam.app.sweep import _stop_overdue, executing_seconds

    scheduler, address = _scheduler(tmp_path)
    dask = Path(sys.executable).with_name("dask")
    command = [str(dask), "worker", address, "--nthreads", "1", "--no-dashboard"]
    workers = [
        subprocess.Popen(command + flag, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for flag in ([], ["--no-nanny"])
    ]
    try:
        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
            nanny = {
                addr: info["nanny"] is not None for addr, info in client.scheduler_info()["workers"].items()
            }
            running = {
                addr: client.submit(time.sleep, 60, workers=[addr], pure=False, key=f"sleep-{i}")
                for i, addr in enumerate(sorted(nanny))
            }
            running = {future.key: future for future in running.values()}
            deadline = time.monotonic() + 60
            while sum(len(keys) for keys in client.run(executing_seconds).values()) < 2:
                assert time.monotonic() < deadline
                time.sleep(0.1)
            time.sleep(0.6)
            stopped = _stop_overdue(client, running, 0.5)
    finally:
        for worker in workers:
            worker.kill()  # the one without a nanny sleeps on; SIGTERM would wait for it
            worker.wait(timeout=30)
        scheduler.terminate()
        scheduler.wait(timeout=30)
    head = "timed out: still computing after 0.5 s (--task-timeout); "
    assert sorted(stopped.values()) == sorted(
        (
            worker,
            head
            + (
                "stopped by restarting its worker"
                if has_nanny
                else "its worker has no nanny to restart it (dask worker --no-nanny) and computes on "
                "until the task ends"
            ),
            has_nanny,  # the process computing it is gone
        )
        for worker, has_nanny in nanny.items()
    )


def test_a_bad_scheduler_file_is_one_line_before_any_work(recordings, tmp_path, capsys, monkeypatch):
    from aslam.app import sweep as sweep_module

    monkeypatch.setattr(sweep_module, "SCHEDULER_FILE_WAIT_S", 0.3)
    sweep = str(_write_sweep(recordings))
    results = tmp_path / "results"
    not_json, no_address = tmp_path / "notes.json", tmp_path / "other.json"
    not_json.write_text("not json\n")
    no_address.write_text('{"type": "Scheduler"}\n')
    cases = [
        (["--scheduler-file", str(tmp_path / "missing.json")], "no such Dask scheduler file (waited 0.3 s"),
        (["--scheduler-file", str(not_json)], "not a Dask scheduler file (no JSON in it after 0.3 s)"),
        (["--scheduler-file", str(no_address)], "not a Dask scheduler file (no 'address')"),
        (["--scheduler-file", str(tmp_path)], "cannot read the Dask scheduler file"),
        (["--scheduler-file", str(no_address), "--scheduler", "tcp://h:1"], "both name the cluster"),
    ]
    for options, needle in cases:
        assert main(["sweep", sweep, "-o", str(results), *options, "-q"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("aslam: error: ") and err.count("\n") == 1 and needle in err, err
    assert not results.exists()


def test_a_rerun_skips_the_done_tasks_and_force_recomputes(local_run, recordings, monkeypatch, tmp_path):
    _code, results = local_run
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # $TMPDIR, as Python read it
    (tmp_path / "tmp").mkdir()
    # A notebook's own setting, which Dask's nanny overwrote (with 1) for good when it spawned workers.
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    sweep = read_sweep_file(_write_sweep(recordings))
    estimates = {p: p.stat().st_mtime_ns for p in (results / "estimates").glob("*.mcap")}
    assert len(estimates) == 2
    # what killed workers of an interrupted run left (no such PID), and a live writer's file
    dead = [
        results / "recordings" / ".x.mcap.partial-999999999",
        results / "estimates" / ".y.mcap.partial-999999999",
    ]
    live = results / "estimates" / f".z.mcap.partial-{os.getpid()}"
    for path in (*dead, live):
        path.write_bytes(b"half a file")
    seen: list[tuple[int, bool]] = []
    run = run_sweep(
        sweep, results, workers=1, on_result=lambda task, _r, reused: seen.append((task.index, reused))
    )
    assert run.reused == 2 and run.failed == 1
    assert not any(path.exists() for path in dead) and live.exists()
    live.unlink()
    assert sorted(seen) == [(0, True), (1, False), (2, True)]  # the failed task is tried again
    assert os.environ["OMP_NUM_THREADS"] == "3" and "MKL_NUM_THREADS" not in os.environ
    assert {p: p.stat().st_mtime_ns for p in (results / "estimates").glob("*.mcap")} == estimates
    assert _figures(_rows(results)) == _figures(_rows(local_run[1]))
    heard: dict[int, list[float]] = {}  # a task's progress events, from Dask's event loop thread
    forced = run_sweep(
        sweep,
        results,
        workers=1,
        force=True,
        on_progress=lambda task, done: heard.setdefault(task.index, []).append(done),
    )
    assert forced.reused == 0
    # every task that estimated said how far it was, within itself (the bar moves within a task)
    assert {r.index for r in forced.results if r.ok} == {0, 2} <= set(heard)
    assert all(0 < done <= 1 and said == sorted(said) for said in heard.values() for done in said)
    assert all(p.stat().st_mtime_ns != mtime for p, mtime in estimates.items())
    assert _same_but_timing(forced.results, run.results)
    assert list((tmp_path / "tmp").iterdir()) == []  # no dask-scratch-space left behind


def _same_but_timing(a: tuple[TaskResult, ...], b: tuple[TaskResult, ...]) -> bool:
    def strip(results):
        return [
            None if r.summary is None else {k: v for k, v in r.summary.items() if not k.startswith("timing.")}
            for r in results
        ]

    return strip(a) == strip(b)


def test_task_keys_follow_the_recording_bytes_and_the_parameters(recordings, tmp_path):
    sweep = read_sweep_file(_write_sweep(recordings))
    first = plan_tasks(sweep, tmp_path)
    assert [t.key for t in first] == [t.key for t in plan_tasks(sweep, tmp_path / "elsewhere")]
    assert len({t.key for t in first}) == 3
    copy = tmp_path / "copy.mcap"
    copy.write_bytes((recordings / "good.mcap").read_bytes())
    other = tmp_path / "sweep.toml"
    other.write_text(f'[recordings]\npaths = ["{copy}"]\n[grid]\nbeta = [3.0, 2.0]\n')
    copied = plan_tasks(read_sweep_file(other), tmp_path / "results")
    assert copied[0].key == first[0].key  # the same bytes and parameters: the same task
    assert copied[1].key != first[0].key
    assert [t.parameters for t in copied] == [(("beta", 3.0),), (("beta", 2.0),)]


def _copy_of_this_aslam(folder: Path, *, edit: str | None = None) -> Path:
    """This aslam's packages copied under ``folder/aslam`` (a regular package there, so nothing of
    another checkout is imported), with ``edit`` appended to core/estimator.py: what a user has
    after an upgrade that changed the estimator but not the version. Returns its PYTHONPATH."""
    import aslam.app.sweep as sweep_module

    root = Path(sweep_module.__file__).resolve().parent.parent
    copy = folder / "aslam"
    for package in ("app", "cli", "core", "data_formats", "recorder"):
        shutil.copytree(root / package, copy / package, ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "__init__.py").write_text("")
    if edit is not None:
        with (copy / "core" / "estimator.py").open("a") as estimator:
            estimator.write(edit)
    return folder


def _planned_by(pythonpath: Path, sweep_file: Path, results: Path) -> list[str]:
    """The task keys and render paths another aslam (at ``pythonpath``) plans for ``sweep_file``."""
    script = (
        "import json, sys\n"
        "import aslam\n"
        f"assert aslam.__file__.startswith({str(pythonpath)!r}), aslam.__file__\n"
        "from aslam.app.sweep import plan_tasks\n"
        "from aslam.app.sweep_file import read_sweep_file\n"
        "tasks = plan_tasks(read_sweep_file(sys.argv[1]), sys.argv[2])\n"
        "print(json.dumps([[t.key, str(t.source.path)] for t in tasks]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(pythonpath), "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run(
        [sys.executable, "-c", script, str(sweep_file), str(results)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout)


def test_results_of_other_code_under_the_same_version_are_never_reused(recordings, tmp_path):
    """A sweep folder kept across an upgrade: the version stayed 0.1.0 through every change of the
    estimator, the scoring and the recorder, and the task keys and render names held only it, so
    the new code took the old code's results and renders for its own (a 2026-12-04 sweep re-run
    today: '4 already done', precision 0.889 where today's estimator gives 0.921). A copy of the
    same code elsewhere keeps the keys; one line more in the estimator changes every one."""
    sweep_file = _write_sweep(recordings)
    results = tmp_path / "results"
    here = [[t.key, str(t.source.path)] for t in plan_tasks(read_sweep_file(sweep_file), results)]
    same = _planned_by(_copy_of_this_aslam(tmp_path / "same"), sweep_file, results)
    edited = _planned_by(_copy_of_this_aslam(tmp_path / "edited", edit="# a release\n"), sweep_file, results)
    assert same == here
    assert len(edited) == len(here) == 3
    assert all(new[0] != old[0] for new, old in zip(edited, here, strict=True))
    assert edited[2][1] != here[2][1]  # the render too: another recorder may render other bytes
    assert [path for _, path in edited[:2]] == [path for _, path in here[:2]]


def _with_library_version(pythonpath: Path, library: str, version: str) -> Path:
    """``library``'s metadata at ``version`` on ``pythonpath``, found before the installed one's: what
    ``pip install -U`` leaves, as far as asking for the version goes (the library itself is the same)."""
    info = pythonpath / f"{library.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {library}\nVersion: {version}\n")
    return pythonpath


def test_results_of_other_libraries_are_never_reused(recordings, tmp_path):
    """``pip install -U numpy`` (2.4.6 -> 2.5.5) moved the last digits of ``report --json``'s errors,
    but the code version hashed aslam's source alone: a sweep resumed after the upgrade took the old
    numpy's results and renders for the new one's, and its table mixed the two. Each library whose
    arithmetic or decoding enters a result now counts by its version, read without importing it."""
    from aslam.data_formats.provenance import RESULT_LIBRARIES, library_versions

    sweep_file = _write_sweep(recordings)
    results = tmp_path / "results"
    here = [[t.key, str(t.source.path)] for t in plan_tasks(read_sweep_file(sweep_file), results)]
    same = _copy_of_this_aslam(tmp_path / "same")
    assert _planned_by(same, sweep_file, results) == here
    assert list(library_versions()) == ["python", *RESULT_LIBRARIES]
    assert "-" not in library_versions().values()  # every one is installed, so every one is read
    for library in ("numpy", "opencv-python-headless"):
        upgraded = _with_library_version(_copy_of_this_aslam(tmp_path / library), library, "99.0.0")
        planned = _planned_by(upgraded, sweep_file, results)
        assert all(new[0] != old[0] for new, old in zip(planned, here, strict=True)), library
        assert planned[2][1] != here[2][1]  # the render too: another numpy may render other bytes
        assert [path for _, path in planned[:2]] == [path for _, path in here[:2]]
    libraries = [
        "numpy",
        "cv2",
        "imagecodecs",
        "faiss",
        "gtsam",
        "evo",
        "scipy",
        "pyrender",
        "trimesh",
        "PIL",
    ]
    script = (
        "import sys\n"
        "from aslam.data_formats.provenance import code_version\n"
        "code_version()\n"
        f"print([name for name in {libraries!r} if name in sys.modules])\n"
    )
    env = {**os.environ, "PYTHONPATH": str(same), "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout  # reading a version imports nothing of the library


def _sourceless(pythonpath: Path) -> Path:
    """The copy at ``pythonpath`` as an install that ships bytecode alone: ``compileall -b`` puts
    each module's .pyc beside it, then the .py files go."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", "-b", str(pythonpath)], check=True)
    for source in pythonpath.rglob("*.py"):
        source.unlink()
    return pythonpath


def _code_version_of(pythonpath: Path) -> str:
    script = "from aslam.data_formats.provenance import code_version\nprint(code_version())\n"
    env = {**os.environ, "PYTHONPATH": str(pythonpath), "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
    return done.stdout.strip()


def test_an_install_of_bytecode_alone_has_a_code_version_of_its_own_code(tmp_path):
    """An install without sources (``compileall -b``, the .py removed) hashed no file at all: every
    such install was 0.1.0+src.e3b0c44298fc, the SHA-256 of nothing, so an upgraded one took a sweep
    folder's old results for its own and a cluster worker of other code passed the check."""
    old = _sourceless(_copy_of_this_aslam(tmp_path / "old"))
    new = _sourceless(_copy_of_this_aslam(tmp_path / "new", edit="# a release\n"))
    assert not list(old.rglob("*.py"))
    versions = {_code_version_of(old), _code_version_of(new)}
    assert len(versions) == 2, versions
    assert not any(version.endswith(hashlib.sha256(b"").hexdigest()[:12]) for version in versions)


def test_the_code_version_reads_modules_alone_not_an_editors_lock_beside_them(tmp_path):
    """Emacs locks a file being edited with a link to nothing, ``.#estimator.py``: the code version
    read it as a module and every sweep stopped ("No such file or directory", exit 2) until the
    file was saved; macOS's ``._estimator.py`` (its metadata beside a file copied from its disks)
    made the same code another version."""
    plain = _copy_of_this_aslam(tmp_path / "plain")
    edited = _copy_of_this_aslam(tmp_path / "edited")
    (edited / "aslam" / "core" / ".#estimator.py").symlink_to("someone@host.1234:1733400000")
    (edited / "aslam" / "recorder" / "._render.py").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    assert _code_version_of(edited) == _code_version_of(plain)


def test_sweep_file_problems_are_one_line_exit_2_naming_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        'bogus = 1\nfigures = ["loop_closure.nope"]\n[recordings]\npaths = ["*.nothing"]\n'
        '[grid]\nbeta = ["x"]\nmax_hypotheses = 2.5\nwhat = 3\ncells_x = [2, 0]\nthumbnail_beta = -2\n'
        '[[render]]\nseeds = [-1]\ncolour = "red"\nlaps = "two"\n'
    )
    assert main(["sweep", str(bad), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"aslam: error: {bad}: ")
    for needle in [
        "unknown key 'bogus'",
        "unknown summary key 'loop_closure.nope'",
        "'*.nothing' matches nothing",
        'grid: beta must be a number, got "x"',
        "grid: max_hypotheses must be a whole number, got 2.5",
        "unknown key 'grid.what'",
        "seed must be ≥ 0, got -1",
        "unknown key 'render.colour'",
        # a mistyped key does not hide the others' values out of range
        "grid: cells_x must be a whole number in [1, 32], got 0",
        "grid: thumbnail_beta must be a number in [0.001, 50], got -2.0",
        'render #1: laps must be a whole number, got "two"',
    ]:
        assert needle in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[grid]\nbeta = [-1.0, 3.0]\n", "beta must be a number in [0.001, 50], got -1.0"),
        ("[grid]\ncandidate_search = ['graph', 'sideways']\n", "candidate_search must be 'graph' or 'path'"),
        (
            "[score]\nradius_m = 0\n[[render]]\nseeds = 1\n",
            "score.radius_m must be a number in [0.001, 1000], got 0.0",
        ),
        (
            "[score]\nradius_m = 5000\n[[render]]\nseeds = 1\n",
            "score.radius_m must be a number in [0.001, 1000], got 5000.0",
        ),
        ("[grid]\nbeta = 3.0\n", "no recordings"),
        ("[[render]]\nroute = 'nowhere'\n", "route 'nowhere' is neither a preset"),
        ("[[render]\n", "not valid TOML"),
        ("[grid]\nbeta = []\n[[render]]\nseeds = 1\n", "grid: beta is an empty list"),
        ("[[render]]\nseeds = []\n", "render #1: seeds is an empty list"),
        ("[[render]]\nlaps = [2, 'two']\n", 'render #1: laps must be a whole number, got "two"'),
        (  # as TOML spells it, not datetime.datetime(1979, …)
            "[grid]\nbeta = 1979-05-27T07:32:00Z\n[[render]]\nseeds = 1\n",
            "grid: beta must be a number, got 1979-05-27T07:32:00+00:00 (a date or time)",
        ),
        ("[grid]\nbeta = [[1.0]]\n[[render]]\nseeds = 1\n", "grid: beta must be a number, got an array"),
    ],
)
def test_sweep_file_values_are_checked_by_building_the_configs(tmp_path, text, needle):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        read_sweep_file(path)
    assert needle in str(caught.value) and str(path) in str(caught.value)


#: A value other than the default for every ``[[render]]`` key but route and seeds.
OTHER_RENDER_SETTINGS = {
    "laps": 3,
    "size": "64x48",
    "noise_model": "paper",
    "noise": 0.05,
    "drift_deg_per_m": 1.0,
    "jitter_m": 0.1,
    "jitter_deg": 2.5,
    "wander_m": 0.2,
    "wander_deg": 1.0,
    "wander_length_m": 5.0,
    "aliasing": 0.5,
    "lighting_change": 0.25,
    "odometry_reset_at": 7,
    "world": "w.obj",
    "fov_deg": 70.0,
    "camera_height_m": 1.0,
    "fps": 2.0,
    "jpeg_quality": 90,
}


def test_every_render_setting_tells_renders_apart_in_the_tables(tmp_path):
    """The tables' render column named route, seed, laps, size, noise and aliasing only: renders
    differing in lighting_change, wander, jitter, fps, … read alike. Now every setting not at its
    default is named, and only those."""
    assert set(OTHER_RENDER_SETTINGS) == set(RENDER_KEYS) - {"route", "seeds"}
    (tmp_path / "w.obj").write_text("")
    render = '[[render]]\nroute = "paper"\nseeds = [1]\n'
    tables = [render] + [
        f"{render}{key} = {json.dumps(value)}\n" for key, value in OTHER_RENDER_SETTINGS.items()
    ]
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text("".join(tables) + "[[grid]]\nbeta = 3.0\n")
    labels = [render_text(config) for config in read_sweep_file(sweep_file).renders]
    shown = {key: f"{v:g}" if isinstance(v, float) else v for key, v in OTHER_RENDER_SETTINGS.items()}
    shown["world"] = tmp_path / "w.obj"
    assert labels == ["route=paper seed=1"] + [
        f"route=paper seed=1 {key}={value}" for key, value in shown.items()
    ]
    assert render_text(RecordConfig(noise=NoiseParams(noise=0.1234567))).endswith(" noise=0.1234567")


def test_render_lists_multiply_and_grids_multiply_in_file_order(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        "[[render]]\nseeds = [1, 2]\nnoise = [0.01, 0.05]\nsize = '64x48'\n"
        "[grid]\ncells_x = [1, 2]\nbeta = [2, 3]\n"
    )
    sweep = read_sweep_file(path)
    assert [(c.seed, c.noise.noise) for c in sweep.renders] == [(1, 0.01), (1, 0.05), (2, 0.01), (2, 0.05)]
    assert [dict(p) for p in sweep.parameter_sets()] == [
        {"cells_x": 1, "beta": 2.0},
        {"cells_x": 1, "beta": 3.0},
        {"cells_x": 2, "beta": 2.0},
        {"cells_x": 2, "beta": 3.0},
    ]
    assert len(plan_tasks(sweep, tmp_path)) == 16


def test_a_sweep_renders_what_aslam_record_renders(tmp_path):
    """Issue 9's knobs (wander, a new light, the paper's noise model, an odometry reset) in a
    [[render]] table give the configuration `aslam record` gives for the same options, the
    noise model's own jitter included."""
    from aslam.recorder.config import NoiseModel, NoiseParams, RecordConfig

    path = tmp_path / "s.toml"
    path.write_text(
        "[[render]]\nseeds = 3\nnoise_model = ['default', 'paper']\nwander_m = 0.3\nwander_deg = 5.0\n"
        "lighting_change = 0.5\nodometry_reset_at = 40\n"
    )
    default, paper = read_sweep_file(path).renders
    for config, model, jitter in (
        (default, NoiseModel.DEFAULT, (0.05, 1.5)),
        (paper, NoiseModel.PAPER, (0.0, 0.0)),
    ):
        noise = NoiseParams.of_model(model, wander_m=0.3, wander_deg=5.0)
        assert config == RecordConfig(seed=3, noise=noise, lighting_change=0.5, odometry_reset_at=40)
        assert (config.noise.jitter_m, config.noise.jitter_deg) == jitter
    path.write_text("[[render]]\nnoise_model = 'papr'\n")
    with pytest.raises(ConfigError, match="noise_model must be one of default, paper"):
        read_sweep_file(path)


def test_every_render_key_is_an_option_of_the_one_record_config_builder():
    """A [[render]] key is either turned into a value by the sweep file's reader (a route file's
    path, the seeds, the size) or passed by its name to ``RecordConfig.from_options``, the builder
    ``aslam record`` calls too: a new knob cannot reach one and not the other."""
    import inspect

    from aslam.app.sweep_file import _RESOLVED_HERE, RENDER_KEYS
    from aslam.recorder.config import RecordConfig

    options = set(inspect.signature(RecordConfig.from_options).parameters)
    assert set(RENDER_KEYS) - set(_RESOLVED_HERE) <= options
    assert set(_RESOLVED_HERE) <= set(RENDER_KEYS)


def test_a_combination_named_twice_runs_once(tmp_path):
    """A value listed twice, or two grids naming the same configuration (``step_m`` at its
    default is the defaults), plan one task each, in first-come order: no duplicate rows, and no
    two workers writing one estimate file."""
    path = tmp_path / "s.toml"
    path.write_text(
        "[[render]]\nseeds = [1]\nsize = '64x48'\n"
        "[[grid]]\ncells_x = [1, 2, 1]\nbeta = [2, 2.0]\n"
        "[[grid]]\ncells_x = [2]\nbeta = [2.0, 3]\n"
    )
    sweep = read_sweep_file(path)
    assert [dict(p) for p in sweep.parameter_sets()] == [
        {"cells_x": 1, "beta": 2.0},
        {"cells_x": 2, "beta": 2.0},
        {"cells_x": 2, "beta": 2.0},
        {"cells_x": 2, "beta": 3.0},
    ]
    tasks = plan_tasks(sweep, tmp_path)
    assert [dict(t.parameters) for t in tasks] == [
        {"cells_x": 1, "beta": 2.0},
        {"cells_x": 2, "beta": 2.0},
        {"cells_x": 2, "beta": 3.0},
    ]
    assert [t.index for t in tasks] == [0, 1, 2]
    assert len({t.estimate_path for t in tasks}) == 3


def test_a_recording_copied_under_another_name_keeps_its_rows_computed_once(recordings, tmp_path, capsys):
    """``cp a.mcap b.mcap``, both matched: each name has its rows (the user finds every recording
    named), the copy's sharing the first's result, computed once; one warning line names both."""
    folder = tmp_path / "recs"
    folder.mkdir()
    for name in ("a.mcap", "b.mcap"):
        (folder / name).write_bytes((recordings / "good.mcap").read_bytes())
    sweep = folder / "s.toml"
    sweep.write_text('figures = ["keyframes"]\n[recordings]\npaths = ["*.mcap"]\n[grid]\nbeta = [2.0, 3.0]\n')
    results = tmp_path / "out"
    assert main(["sweep", str(sweep), "-o", str(results), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if "warning" in line]
    assert warning == [
        f"aslam: warning: {folder / 'b.mcap'}: the same bytes as {folder / 'a.mcap'};"
        " its rows share that recording's results (computed once)"
    ]
    assert "4 tasks, 0 already done, 2 to run, 2 shared with an identical recording" in err
    rows = _rows(results)
    assert [(Path(r["recording"]).name, r["param.beta"]) for r in rows] == [
        ("a.mcap", 2.0),
        ("a.mcap", 3.0),
        ("b.mcap", 2.0),
        ("b.mcap", 3.0),
    ]
    assert [r["key"] for r in rows[2:]] == [r["key"] for r in rows[:2]]
    assert all(r["status"] == "ok" for r in rows)
    copied = [{**row, "task": row["task"] + 2, "same_as": row["task"]} for row in _figures(rows[:2])]
    assert _figures(rows[2:]) == copied
    assert len(list((results / "estimates").glob("*.mcap"))) == 2  # computed once each
    assert [r["same_as"] for r in rows] == [None, None, 0, 1]  # the table says whose result it is
    tasks = plan_tasks(read_sweep_file(sweep), results)
    assert [t.same_as for t in tasks] == [None, None, 0, 1]
    assert main(["sweep", str(sweep), "-o", str(results), "-q"]) == 0  # all done: no cluster needed
    assert _rows(results) == rows


def test_recordings_of_one_name_are_told_apart_by_their_folders_on_the_terminal(tmp_path, capsys):
    """``x/run.mcap`` and ``y/deep/run.mcap`` are two lines the user can tell apart in the tables
    on the terminal (the plan, the live table, --pareto), each by the shortest tail of its path no
    other recording has; a name no other has stays a name; the files keep the whole path."""
    paths = ["x/run.mcap", "y/deep/run.mcap", "z/deep/run.mcap", "a.mcap"]
    for seed, path in enumerate(paths):
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        write_recording(tmp_path / path, random_frames(2, seed=seed))
    sweep = tmp_path / "s.toml"
    sweep.write_text(f"[recordings]\npaths = {json.dumps(paths)}\n[grid]\nbeta = 3.0\n")
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--dry-run"]) == 0
    out = capsys.readouterr().out
    recordings = [line.split("│")[2].strip() for line in out.splitlines() if line.startswith("│")]
    assert recordings == ["x/run.mcap", "y/deep/run.mcap", "z/deep/run.mcap", "a.mcap"]
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--dry-run", "--json", "-"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [row["recording"] for row in rows] == [str(tmp_path / path) for path in paths]
    inner, outer = Path("/x/run.mcap"), Path("/data/x/run.mcap")  # every tail of one is the other's
    assert distinct_names([inner, outer]) == {inner: "/x/run.mcap", outer: "data/x/run.mcap"}


def test_recording_paths_with_brackets_are_names_and_globs_only_in_the_pattern(tmp_path):
    """A sweep file in ``dir[1]/`` lists its own ``rec.mcap`` (not ``dir1/rec.mcap``, which the
    folder's name read as a glob would match); a file whose name holds brackets is taken as named;
    the pattern's own wildcards still glob, inside the literal folder."""
    for folder in ("dir[1]", "dir1"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "rec.mcap").write_bytes(b"x")
    (tmp_path / "dir[1]" / "odd[bold].mcap").write_bytes(b"x")
    sweep_file = tmp_path / "dir[1]" / "s.toml"
    for paths, expected in (
        ('["rec.mcap"]', ["rec.mcap"]),
        ('["odd[bold].mcap"]', ["odd[bold].mcap"]),
        ('["*.mcap"]', ["odd[bold].mcap", "rec.mcap"]),
    ):
        sweep_file.write_text(f"[recordings]\npaths = {paths}\n")
        found = [recording.path for recording in read_sweep_file(sweep_file).recordings]
        assert [p.name for p in found] == expected
        assert all(p.parent == tmp_path / "dir[1]" for p in found)


def test_pareto_names_map_to_summary_keys_with_a_direction():
    objectives = resolve_objectives(
        "precision,recall,keyframes_per_second,first_delay_keyframes,best.x_m.max"
    )
    assert objectives == [
        Objective("loop_closure.precision", True),
        Objective("loop_closure.recall", True),
        Objective("timing.keyframes_per_second", True),
        Objective("relocalisation.first_delay_keyframes", False),
        Objective("error.best.x_m.max", False),
    ]
    assert resolve_objectives("-hypotheses.max,+error.best.x_m.max") == [
        Objective("hypotheses.max", False),
        Objective("error.best.x_m.max", True),
    ]
    with pytest.raises(InputError, match=r"'max' is ambiguous .*'nope' is not a summary key"):
        resolve_objectives("max,nope")
    # a figure twice gave two identical columns; both ways put every task in the set
    with pytest.raises(InputError, match=r"'loop_closure.precision' names loop_closure.precision again"):
        resolve_objectives("precision,loop_closure.precision")
    with pytest.raises(InputError, match=r"'precision' names loop_closure.precision again"):
        resolve_objectives("-precision,+precision")


def _result(index: int, values: list[float | None]) -> TaskResult:
    summary = {f"f{i}": v for i, v in enumerate(values)}
    return TaskResult(index, str(index), summary, None, (), 1.0, 1.0, "w")


@given(st.lists(st.lists(st.integers(0, 4), min_size=2, max_size=2), min_size=1, max_size=25))
def test_the_pareto_front_is_exactly_the_undominated_results(points):
    objectives = [Objective("f0", True), Objective("f1", False)]
    results = [_result(i, p) for i, p in enumerate(points)]
    front = pareto_front(results, objectives)

    def better_or_equal(a, b):
        return a[0] >= b[0] and a[1] <= b[1]

    for r in results:
        p = points[r.index]
        dominated = any(better_or_equal(q, p) and q != p for q in points)
        assert (r in front) == (not dominated)
    assert [r.index for r in front] == sorted(r.index for r in front)


def test_the_pareto_front_leaves_out_failed_and_unmeasured_results():
    failed = TaskResult(9, "9", None, "boom", (), None, None, "w")
    front = pareto_front(
        [_result(0, [1, None]), _result(1, [0, 0]), failed], [Objective("f0", True), Objective("f1", True)]
    )
    assert [r.index for r in front] == [1]


def test_the_example_sweep_file_is_valid_and_its_paper_grid_is_the_paper_estimator(tmp_path, capsys):
    """`aslam sweep --example > sweep.toml` (nothing else needed; a wheel has no docs/ folder, where
    the README sent a sweep user): every parameter set builds, and `paper_faithful = true` is
    `aslam estimate --paper-faithful`'s configuration with the grid's keys changed, not a guess at it."""
    from dataclasses import replace

    from aslam.app.sweep_file import estimator_config
    from aslam.core.config import EstimatorConfig

    assert main(["sweep", "--example"]) == 0
    example = tmp_path / "sweep.toml"
    example.write_text(capsys.readouterr().out, encoding="utf-8")
    sweep = read_sweep_file(example)
    sets = list(sweep.parameter_sets())
    assert len(sweep.renders) == 5 and len(sets) == 6 + 2
    assert len(plan_tasks(sweep, tmp_path)) == 40
    assert estimator_config(sets[-1]) == replace(EstimatorConfig.paper_faithful(), beta=3.0)
    assert estimator_config(sets[0]).observation_model == "thumbnail"


def test_estimate_with_the_reader_in_process_writes_the_same_bytes(recordings, tmp_path):
    """What sweep tasks run (no reader child, as Dask workers are daemonic; histograms in the
    calling thread) is what `aslam estimate` runs."""
    from aslam.app.estimate import estimate
    from aslam.core.config import EstimatorConfig

    recording = recordings / "good.mcap"
    forked, in_process = tmp_path / "forked.mcap", tmp_path / "in_process.mcap"
    estimate(recording, forked, EstimatorConfig(), timing=False)
    summary = estimate(
        recording, in_process, EstimatorConfig(), timing=False, workers=0, reader_process=False
    )
    assert summary.keyframes > 20
    assert forked.read_bytes() == in_process.read_bytes()


def test_a_bad_scheduler_address_is_exit_2(recordings, tmp_path, capsys):
    sweep = _write_sweep(tmp_path)
    (tmp_path / "good.mcap").symlink_to(recordings / "good.mcap")
    (tmp_path / "corrupt.mcap").symlink_to(recordings / "corrupt.mcap")
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--scheduler", "nonsense", "-q"]) == 2
    assert "cannot reach the Dask scheduler at nonsense" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # the folder it made for the run is gone with it
    code = main(
        ["sweep", str(sweep), "-o", str(tmp_path / "out"), "--scheduler", "tcp://x:1", "--workers", "2"]
    )
    assert code == 2 and "--workers sizes a local cluster" in capsys.readouterr().err


def test_a_local_cluster_that_cannot_start_leaves_no_scratch_folder(tmp_path, monkeypatch):
    """The cluster's own scratch folder was made before the cluster and removed only with it: a
    worker that could not start (here a preload that raises) left one behind at every attempt."""
    import dask

    preload = tmp_path / "bad_preload.py"
    preload.write_text("raise RuntimeError('this worker cannot start')\n")
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    with dask.config.set({"distributed.worker.preload": [str(preload)]}), pytest.raises(RuntimeError):
        open_client(workers=1, scheduler=None)
    assert list((tmp_path / "tmp").iterdir()) == []


def test_a_client_that_could_not_connect_is_gone_at_once(tmp_path):
    """Left to the garbage collector, it would be closed at a random later moment, which inside
    another Client's start deadlocks distributed (it hung the suite once)."""
    import gc

    import distributed

    gc.disable()  # only an explicit collection may free it
    try:
        with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
            open_client(workers=None, scheduler="nonsense")
        left = [o for o in gc.get_objects() if isinstance(o, distributed.Client) and "nonsense" in repr(o)]
    finally:
        gc.enable()
    assert left == []


def test_several_grids_run_in_turn_and_every_row_shows_the_effective_values(tmp_path, recordings):
    path = tmp_path / "s.toml"
    path.write_text(
        f'[recordings]\npaths = ["{recordings / "good.mcap"}"]\n'
        "[[grid]]\nbeta = [2.0, 3.0]\n"
        "[[grid]]  # the paper's estimator\ncells_x = 1\ncandidate_search = 'path'\n"
    )
    sweep = read_sweep_file(path)
    assert [dict(p) for p in sweep.parameter_sets()] == [
        {"beta": 2.0},
        {"beta": 3.0},
        {"cells_x": 1, "candidate_search": "path"},
    ]
    assert sweep.parameter_names() == ("beta", "cells_x", "candidate_search")
    tasks = plan_tasks(sweep, tmp_path)
    results = [TaskResult(t.index, t.key, {}, None, (), 1.0, 1.0, "w") for t in tasks]
    table = [{k: v for k, v in row.items() if k.startswith("param.")} for row in rows(sweep, tasks, results)]
    assert table == [
        {"param.beta": 2.0, "param.cells_x": 2, "param.candidate_search": "graph"},
        {"param.beta": 3.0, "param.cells_x": 2, "param.candidate_search": "graph"},
        {"param.beta": 3.0, "param.cells_x": 1, "param.candidate_search": "path"},
    ]
    # ``paper_faithful`` is a grid key, no field of the configuration: its column says which grid
    # started from the paper's estimator (it held the classmethod, and the tables failed: exit 70).
    path.write_text(
        f'[recordings]\npaths = ["{recordings / "good.mcap"}"]\n'
        "[[grid]]\nbeta = 2.0\n[[grid]]\npaper_faithful = true\n"
    )
    sweep = read_sweep_file(path)
    tasks = plan_tasks(sweep, tmp_path)
    results = [TaskResult(t.index, t.key, {}, None, (), 1.0, 1.0, "w") for t in tasks]
    assert [row["param.paper_faithful"] for row in rows(sweep, tasks, results)] == [False, True]
    assert arrow_table(sweep, tasks, results).column("param.paper_faithful").to_pylist() == [False, True]
    bad = tmp_path / "bad.toml"
    bad.write_text("[[render]]\n[[grid]]\nbeta = 1.0\n[[grid]]\nbeta = -1.0\n")
    with pytest.raises(ConfigError, match=r"grid #2: beta must be a number in \[0\.001, 50\]"):
        read_sweep_file(bad)


def test_recording_hashes_are_kept_while_path_size_and_mtime_hold(recordings, tmp_path):
    from aslam.app.sweep import HashCache
    from aslam.data_formats.files import source_sha256

    recording = tmp_path / "r.mcap"
    recording.write_bytes((recordings / "good.mcap").read_bytes())
    real = source_sha256(recording)
    cache = HashCache(tmp_path / "hashes.json")
    assert cache.sha256(recording) == real
    cache.save()
    saved = json.loads((tmp_path / "hashes.json").read_text())
    saved[str(recording)]["sha256"] = "0" * 64  # what a re-run would take without reading the file
    (tmp_path / "hashes.json").write_text(json.dumps(saved))
    assert HashCache(tmp_path / "hashes.json").sha256(recording) == "0" * 64
    assert HashCache(tmp_path / "hashes.json", use=False).sha256(recording) == real  # --force
    os.utime(recording, ns=(0, 0))
    assert HashCache(tmp_path / "hashes.json").sha256(recording) == real  # touched: read again


def _bag_folder(folder: Path) -> Path:
    """A rosbag2-shaped folder: metadata.yaml listing one storage file (hashing reads bytes only)."""
    folder.mkdir(parents=True)
    (folder / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  relative_file_paths:\n  - bag_0.mcap\n"
    )
    (folder / "bag_0.mcap").write_bytes(b"first bag's bytes")
    return folder


def test_a_bag_file_rewritten_in_place_is_hashed_again(tmp_path):
    """A bag folder's own size and mtime stay when a file in it is rewritten in place: the cache
    kept the old bag's hash, a re-run its results, and each new task failed for good."""
    from aslam.app.sweep import HashCache
    from aslam.data_formats.files import source_sha256

    bag = _bag_folder(tmp_path / "bag")
    cache = HashCache(tmp_path / "hashes.json")
    first = cache.sha256(bag)
    cache.save()
    folder_times = os.stat(bag).st_atime_ns, os.stat(bag).st_mtime_ns
    (bag / "bag_0.mcap").write_bytes(b"other bag's bytes")  # same size, the folder untouched
    os.utime(bag, ns=folder_times)
    again = HashCache(tmp_path / "hashes.json").sha256(bag)
    assert again == source_sha256(bag) != first


def test_files_beside_a_bag_in_its_folder_are_no_part_of_it(tmp_path):
    """A rosbag2 folder is its metadata.yaml and the files it lists: a README, or a sweep's own
    results written into the folder (``-o .``), changed the bag's identity, and every task failed
    as "not the bytes the sweep planned"."""
    from aslam.data_formats.files import source_files, source_sha256

    bag = _bag_folder(tmp_path / "bag")
    before = source_sha256(bag)
    (bag / "README.md").write_text("notes")
    (bag / "results.parquet").write_bytes(b"PAR1")
    assert [p.name for p in source_files(bag)] == ["bag_0.mcap", "metadata.yaml"]
    assert source_sha256(bag) == before
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {relative_file_paths: [../x]}\n")
    everything = ["README.md", "bag_0.mcap", "metadata.yaml", "results.parquet"]
    assert [p.name for p in source_files(bag)] == everything  # a listing outside the folder: all of it


def test_pareto_prints_the_undominated_tasks_on_stdout(local_run, recordings, capsys):
    _code, results = local_run
    sweep = _write_sweep(recordings)
    code = main(["sweep", str(sweep), "-o", str(results), "--pareto", "precision,recall,best.x_m.mean", "-q"])
    assert code == 3  # the corrupt recording fails again
    out = capsys.readouterr().out
    assert "Pareto set:" in out and "↑ loop_closure.precision" in out and "↓ error.best.x_m.mean" in out
    ok = [r for r in _rows(results) if r["status"] == "ok"]
    objectives = resolve_objectives("precision,recall,best.x_m.mean")
    expected = pareto_front(
        [TaskResult(r["task"], r["key"], r, None, (), 1.0, 1.0, "w") for r in ok], objectives
    )
    listed = {int(line.split("│")[1]) for line in out.splitlines() if line.startswith("│")}
    assert listed == {r.index for r in expected} and 1 not in listed and listed


@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
def test_a_recording_that_is_no_regular_file_is_refused_not_hashed_forever(tmp_path, capsys, special):
    """A sweep hashes its recordings before anything runs: a FIFO would block that, /dev/zero never end."""
    if special == "fifo":
        os.mkfifo(tmp_path / "fifo.mcap")
        special = str(tmp_path / "fifo.mcap")
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'[recordings]\npaths = ["{special}"]\n')
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--workers", "1", "-q"]) == 2
    assert "is not a regular file" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_edited_route_file_is_another_render(tmp_path):
    """A render's identity holds the route file's bytes: edited, it is rendered again, never the
    old recording reused under the same name."""
    route = tmp_path / "route.json"
    route.write_text(
        '{"actions": [{"forward_m": 2}, {"turn_deg": 180}, {"forward_m": 2}, {"turn_deg": 180}]}'
    )
    first = render_path(tmp_path, RecordConfig(route=str(route)))
    assert render_path(tmp_path, RecordConfig(route=str(route))) == first
    route.write_text(
        '{"actions": [{"forward_m": 3}, {"turn_deg": 180}, {"forward_m": 3}, {"turn_deg": 180}]}'
    )
    assert render_path(tmp_path, RecordConfig(route=str(route)))[1] != first[1]


def test_an_edited_texture_or_material_of_a_world_is_another_render(tmp_path):
    """A world file's companions (an .obj's .mtl and its texture, a .gltf's buffers) change what is
    rendered: each is in the render's identity. Only the named file counted: a sweep reused the
    render of the old texture. A self-contained world's identity lists no companions."""
    from dataclasses import asdict

    import trimesh
    from PIL import Image

    from aslam.app.sweep import _digest
    from aslam.data_formats.files import source_sha256
    from aslam.data_formats.provenance import code_version

    floor = trimesh.creation.box(extents=(10, 10, 0.1))
    uv = (floor.vertices[:, :2] + 5) / 10
    floor.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (8, 8), (90, 30, 30)))
    floor.export(tmp_path / "floor.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["floor.obj", "material.mtl", "material_0.png"]
    config = RecordConfig(world=tmp_path / "floor.obj")
    first = render_path(tmp_path / "out", config)
    assert render_path(tmp_path / "out", config) == first
    Image.new("RGB", (8, 8), (30, 90, 30)).save(tmp_path / "material_0.png")
    textured = render_path(tmp_path / "out", config)
    assert textured[1] != first[1]
    mtl = tmp_path / "material.mtl"
    mtl.write_text(mtl.read_text().replace("Kd 0.4", "Kd 0.8"))
    assert render_path(tmp_path / "out", config)[1] not in (first[1], textured[1])

    floor.export(tmp_path / "floor.glb")
    glb = RecordConfig(world=tmp_path / "floor.glb")
    before = _digest(
        {
            "render": {**asdict(glb), "world": "floor.glb"},
            "files": {"world": source_sha256(tmp_path / "floor.glb")},
            "version": code_version(),
        }
    )
    assert render_path(tmp_path / "out", glb)[1] == before


def test_a_route_file_in_another_folder_is_the_same_render(tmp_path):
    """A recording holds its route file's name and bytes, not its folder: a sweep's folder copied
    elsewhere (another checkout, a CI cache) names the same render, so its task keys are the same.
    The identity held the absolute path: a moved sweep rendered and estimated everything again."""
    text = '{"actions": [{"forward_m": 2}, {"turn_deg": 180}, {"forward_m": 2}, {"turn_deg": 180}]}'
    routes = [tmp_path / "a" / "loop.json", tmp_path / "b" / "c" / "loop.json", tmp_path / "a" / "lap.json"]
    for route in routes:
        route.parent.mkdir(parents=True, exist_ok=True)
        route.write_text(text)
    here, there, renamed = (render_path(tmp_path / "out", RecordConfig(route=str(r))) for r in routes)
    assert here == there
    assert renamed[1] != here[1]  # the name is in the recording (its route's name)


def test_the_plan_counts_only_the_renders_still_to_make(tmp_path):
    """A re-run whose renders are there renders nothing first (it said it would); --force renders
    them all again; a recording file is never a render."""
    from types import SimpleNamespace

    from aslam.app.sweep import SweepPlan

    made, missing = tmp_path / "made.mcap", tmp_path / "missing.mcap"
    made.write_bytes(b"x")

    def task(path: Path, render: object) -> SimpleNamespace:
        return SimpleNamespace(source=SimpleNamespace(path=path, render=render))

    to_run = (task(made, "cfg"), task(made, "cfg"), task(missing, "cfg"), task(tmp_path / "rec.mcap", None))
    assert SweepPlan((), {}, to_run).renders_due == 1  # type: ignore[arg-type]
    assert SweepPlan((), {}, to_run, force=True).renders_due == 2  # type: ignore[arg-type]


def test_every_summary_figure_has_the_direction_a_user_means():
    """Pareto's default direction for each summary key: the costs and errors small, the rest large.
    The large ones are listed in full: a figure added to the summary is maximised unless
    ``app.score.lower_is_better`` says otherwise, and it fails here until someone decided which
    (``loop_closure.wrong``, tried on 2026-12-05, was maximised)."""
    from aslam.app.score import lower_is_better, summary_keys

    smaller = {key for key in summary_keys() if lower_is_better(key)}
    for key in ("trajectory.ape_m.rmse", "trajectory.odometry_rpe_deg.max", "error.best.x_m.mean"):
        assert key in smaller
    for key in ("relocalisation.first_delay_keyframes", "timing.slam_ms_per_keyframe"):
        assert key in smaller
    assert {"trajectory.closures_outvoted", "loop_closure.unjudged_claims"} <= smaller
    larger = set(summary_keys()) - smaller
    assert larger == {
        "keyframes", "states", "links", "ground_truth", "hypotheses.max", "hypotheses.mean",
        "hypotheses.final", "relocalisation.episodes", "loop_closure.claims", "loop_closure.correct",
        "loop_closure.ground_truth_revisits", "loop_closure.precision", "loop_closure.recall",
        "loop_closure.recall_at_full_precision", "loop_closure.auc", "committed.claims",
        "committed.correct", "committed.precision", "committed.recall", "timing.keyframes_per_second",
        "trajectory.closures",
    }  # fmt: skip


def _scheduler(tmp_path: Path) -> tuple[subprocess.Popen, str]:
    """A real `dask scheduler` process with no workers, and its address."""
    scheduler_file = tmp_path / "scheduler.json"
    dask = Path(sys.executable).with_name("dask")
    process = subprocess.Popen(
        [str(dask), "scheduler", "--port", "0", "--no-dashboard", "--scheduler-file", str(scheduler_file)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while not scheduler_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    return process, json.loads(scheduler_file.read_text())["address"]


@contextlib.contextmanager
def _dask_worker(address: str, *, pythonpath: Path | None = None) -> Iterator[None]:
    """A real `dask worker` process of one worker joined to ``address`` while the block runs, its
    aslam imported from ``pythonpath`` where one is given (another checkout's)."""
    dask = Path(sys.executable).with_name("dask")
    env = (
        None
        if pythonpath is None
        else {**os.environ, "PYTHONPATH": str(pythonpath), "PYTHONDONTWRITEBYTECODE": "1"}
    )
    worker = subprocess.Popen(
        [str(dask), "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        yield
    finally:
        worker.terminate()
        worker.wait(timeout=30)


def test_a_cluster_that_cannot_run_the_tasks_is_one_line_not_a_wait_for_ever(
    recordings, tmp_path, capsys, monkeypatch
):
    """A scheduler with no workers, one whose workers run another aslam, a port where no scheduler
    answers, a transport without its settings: exit 2 with one line, and nothing left behind."""
    import socket

    from aslam.app import sweep as sweep_module

    monkeypatch.setattr(sweep_module, "WORKERS_WAIT_S", 1.0)
    monkeypatch.setattr(sweep_module, "SCHEDULER_ANSWER_S", 1.0)
    sweep_file = _write_sweep(recordings)
    process, address = _scheduler(tmp_path)
    try:
        results = tmp_path / "none"
        code = main(["sweep", str(sweep_file), "-o", str(results), "--scheduler", address, "-q"])
        err = capsys.readouterr().err
        assert code == 2, err
        assert f"the Dask cluster at {address} has no workers (waited 1 s)" in err
        assert not results.exists()
        with _dask_worker(address):
            with Client(
                address, timeout=30
            ) as client:  # the worker has joined (1 s is the sweep's patience here)
                client.wait_for_workers(1, timeout=60)
            monkeypatch.setattr("aslam.data_formats.provenance.VERSION", "0.0.0-another")  # here, not there
            assert main(["sweep", str(sweep_file), "-o", str(results), "--scheduler", address, "-q"]) == 2
            err = capsys.readouterr().err
            assert "runs aslam" in err and "this is aslam 0.0.0-another" in err and err.count("\n") == 1
    finally:
        process.terminate()
        process.wait(timeout=30)
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(1)
    port = silent.getsockname()[1]
    try:
        args = ["sweep", str(sweep_file), "-o", str(tmp_path / "x"), "--scheduler", f"tcp://127.0.0.1:{port}"]
        assert main([*args, "-q"]) == 2
        assert "nothing answers as a Dask scheduler" in capsys.readouterr().err
    finally:
        silent.close()
    # A service that speaks first (SSH): its banner was read as a frame's length, "MemoryError:
    # Unable to allocate 2.82 EiB".
    banner = socket.socket()
    banner.bind(("127.0.0.1", 0))
    banner.listen(1)
    speaking = threading.Thread(
        target=lambda: banner.accept()[0].sendall(b"SSH-2.0-OpenSSH_9.6\r\n"), daemon=True
    )
    speaking.start()
    try:
        args = [
            "sweep",
            str(sweep_file),
            "-o",
            str(tmp_path / "z"),
            "--scheduler",
            f"tcp://127.0.0.1:{banner.getsockname()[1]}",
        ]
        assert main([*args, "-q"]) == 2
        assert "something else answers at tcp://127.0.0.1:" in capsys.readouterr().err
    finally:
        banner.close()
    tls = ["sweep", str(sweep_file), "-o", str(tmp_path / "y"), "--scheduler", "tls://127.0.0.1:1", "-q"]
    assert main(tls) == 2
    assert "cannot reach the Dask scheduler at tls://127.0.0.1:1" in capsys.readouterr().err


def test_a_worker_running_other_code_of_the_same_version_is_refused(recordings, tmp_path, capsys):
    """The cluster's workers were checked for the version alone, 0.1.0 through every change: a
    worker left on an older checkout computed with its own estimator and filed the results under
    this code's task keys."""
    edited = _copy_of_this_aslam(tmp_path / "edited", edit="# a release\n")
    err = _sweep_refused_on_a_worker_over(edited, recordings, tmp_path, capsys)
    assert "runs aslam 0.1.0+src." in err and "; this is aslam 0.1.0+src." in err


def test_a_worker_with_another_library_version_is_refused_by_its_name(recordings, tmp_path, capsys):
    """A worker of the same aslam over another numpy computes other last digits and would file them
    under this process's task keys; it is refused, and the line names the library to reinstall
    rather than two code versions that differ in nothing the user can see."""
    upgraded = _with_library_version(_copy_of_this_aslam(tmp_path / "upgraded"), "numpy", "99.0.0")
    err = _sweep_refused_on_a_worker_over(upgraded, recordings, tmp_path, capsys)
    assert " runs numpy 99.0.0; here numpy 2." in err


def _sweep_refused_on_a_worker_over(pythonpath, recordings, tmp_path, capsys) -> str:
    """A sweep on a cluster whose one worker imports from ``pythonpath``: refused in one line (exit
    2) before any task ran; that line."""
    process, address = _scheduler(tmp_path)
    try:
        with _dask_worker(address, pythonpath=pythonpath):
            results = tmp_path / "results"
            code = main(
                ["sweep", str(_write_sweep(recordings)), "-o", str(results), "--scheduler", address, "-q"]
            )
    finally:
        process.terminate()
        process.wait(timeout=30)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1, err
    assert not (results / "tasks").exists()
    return err


def test_a_glob_never_takes_the_sweeps_own_outputs_and_grids_are_bounded(recordings, tmp_path, monkeypatch):
    """Run twice with `**/*.mcap` and the results inside the sweep's folder: the second run's glob
    matches the first run's renders and estimates, which are outputs, not recordings."""
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "good.mcap").write_bytes((recordings / "good.mcap").read_bytes())
    (folder / "results" / "recordings").mkdir(parents=True)  # where its renders go
    (folder / "results" / "recordings" / "old.mcap").write_bytes((recordings / "good.mcap").read_bytes())
    path = folder / "s.toml"
    path.write_text("[recordings]\npaths = ['**/*.mcap']\n")
    sweep = read_sweep_file(path)
    assert len(sweep.recordings) == 2
    assert [t.source.path.name for t in plan_tasks(sweep, folder / "results")] == ["good.mcap"]
    monkeypatch.setattr("aslam.app.sweep_file.MAX_COMBINATIONS", 10)
    path.write_text(f"[grid]\nbeta = {[1.0 + i / 10 for i in range(11)]}\n")
    with pytest.raises(ConfigError, match="grid: 11 parameter sets; at most 10 "):
        read_sweep_file(path)
    path.write_text(f"[[render]]\nseeds = {list(range(11))}\n")
    with pytest.raises(ConfigError, match="render #1: 11 recordings; at most 10 "):
        read_sweep_file(path)


def test_the_tables_keep_the_summarys_types_even_when_every_task_failed(local_run, recordings, tmp_path):
    """A count is an int64 column and ground_truth a bool one, measured or null: two sweeps' tables
    concatenate whatever failed. The list of counts is checked against a real summary's ints."""
    from aslam.app.score import BOOLEAN_KEYS, COUNT_KEYS
    from aslam.app.sweep import arrow_table, load_result

    _code, results = local_run
    sweep = read_sweep_file(_write_sweep(recordings))
    tasks = plan_tasks(sweep, results)
    done = [load_result(results, task) for task in tasks]
    summary = next(r.summary for r in done if r is not None and r.summary is not None)
    ints = {k for k, v in summary.items() if isinstance(v, int) and not isinstance(v, bool)}
    assert ints <= COUNT_KEYS and {k for k, v in summary.items() if isinstance(v, bool)} == BOOLEAN_KEYS
    measured = {k for k in COUNT_KEYS if summary.get(k) is not None}
    assert measured == ints  # every count the summary measured is an int, and no other key is
    failed = [TaskResult(t.index, t.key, None, "failed", (), None, None, "") for t in tasks]
    extra = arrow_table(sweep, tasks, failed, ["loop_closure.claims", "ground_truth"])
    assert str(extra.schema.field("keyframes").type) == "int64"
    assert str(extra.schema.field("loop_closure.claims").type) == "int64"
    assert str(extra.schema.field("ground_truth").type) == "bool"
    assert str(extra.schema.field("same_as").type) == "int64"  # null: no copies in this sweep
    good = pyarrow.parquet.read_table(results / "results.parquet")
    table = arrow_table(sweep, tasks, failed)
    assert pyarrow.concat_tables([good, table]).num_rows == 2 * len(tasks)


def test_a_scheduler_is_asked_who_it_is_even_from_inside_an_event_loop(tmp_path):
    """A notebook runs an event loop; the probe of --scheduler must not need the caller's thread."""
    import asyncio

    from aslam.app.sweep import _probe_scheduler

    process, address = _scheduler(tmp_path)
    try:

        async def from_a_loop() -> None:
            _probe_scheduler(address)  # raises InputError if it cannot ask

        asyncio.run(from_a_loop())
    finally:
        process.terminate()
        process.wait(timeout=30)


# Parameter values as a sweep file may give them: ints for floats (3 is 3.0), a default among them
# (cells_x 2, beta 3.0, max_hypotheses 50, map_reference_scale 0.0), -0.0 (which is 0.0).
GRID_VALUES = {
    "cells_x": [1, 2, 3],
    "beta": [2, 3, 3.0, 4.5],
    "max_hypotheses": [10, 50],
    "map_reference_scale": [0.0, -0.0, 1.0],
}
grid_tables = st.lists(
    st.lists(st.sampled_from(sorted(GRID_VALUES)), min_size=1, max_size=3, unique=True).flatmap(
        lambda names: st.tuples(
            *[st.lists(st.sampled_from(GRID_VALUES[n]), min_size=1, max_size=3) for n in names]
        ).map(lambda lists: dict(zip(names, lists, strict=True)))
    ),
    min_size=1,
    max_size=3,
)


def _grid_sweep(path: Path, grids: list[dict[str, list]]) -> Path:
    text = "[[render]]\nseeds = [1]\nsize = '64x48'\n"
    for grid in grids:
        text += "[[grid]]\n" + "".join(f"{name} = {json.dumps(values)}\n" for name, values in grid.items())
    path.write_text(text)
    return path


@settings(max_examples=40, deadline=None)
@given(grid_tables)
def test_a_grid_is_the_product_of_its_values_and_each_configuration_one_task(tmp_path_factory, grids):
    """Each [[grid]] is the product of its distinct values in file order (the last key fastest), the
    grids in turn; the plan has one task per distinct configuration, in first-come order, with keys
    that are the same on every plan and whatever order a grid's keys are written in."""
    from dataclasses import replace

    from aslam.core.config import EstimatorConfig

    folder = tmp_path_factory.mktemp("grid")
    sweep = read_sweep_file(_grid_sweep(folder / "a.toml", grids))
    kinds = {name: kind for name, kind, _default, _help in EstimatorConfig.parameters()}
    expected_sets = []
    for grid in grids:
        names = list(grid)
        distinct = [list(dict.fromkeys(kinds[name](v) for v in grid[name])) for name in names]
        expected_sets += [tuple(zip(names, values, strict=True)) for values in itertools.product(*distinct)]
    assert list(sweep.parameter_sets()) == expected_sets

    configs = list(dict.fromkeys(replace(EstimatorConfig(), **dict(s)) for s in expected_sets))
    tasks = plan_tasks(sweep, folder / "results")
    assert [t.config for t in tasks] == configs
    assert [t.index for t in tasks] == list(range(len(tasks)))
    assert len({t.key for t in tasks}) == len({t.estimate_path for t in tasks}) == len(tasks)
    assert [t.key for t in plan_tasks(sweep, folder / "results")] == [t.key for t in tasks]
    reordered = [dict(reversed(grid.items())) for grid in grids]
    again = plan_tasks(read_sweep_file(_grid_sweep(folder / "b.toml", reordered)), folder / "results")
    assert {t.key for t in again} == {t.key for t in tasks}


def test_a_recording_whose_name_is_not_utf8_has_its_row_in_the_tables(tmp_path, recordings):
    """``$'\\xff.mcap'`` (``\\udcff`` to Python) stopped the sweep at its end, exit 70: Parquet and
    CSV text is UTF-8. The byte is written as U+FFFD."""
    source = tmp_path / os.fsdecode(b"\xff.mcap")  # no TOML text can name it: a glob finds it
    shutil.copy(recordings / "good.mcap", source)
    path = tmp_path / "s.toml"
    path.write_text('[recordings]\npaths = ["*.mcap"]\n')
    sweep = read_sweep_file(path)
    tasks = plan_tasks(sweep, tmp_path / "out")
    assert [task.source.path for task in tasks] == [source]
    results = [TaskResult(t.index, t.key, {}, None, (), 1.0, 1.0, "w") for t in tasks]
    tables = table_bytes(sweep, tasks, results)
    assert f"{tmp_path}/\ufffd.mcap" in tables["results.csv"].decode()


def test_the_live_table_shows_a_name_with_control_characters_escaped(tmp_path, recordings):
    """The live table's rows printed a recording's name raw: its newline broke the row in two, its
    escape sequence recoloured the terminal."""
    import io

    from rich.console import Console

    from aslam.cli.output import Terminal
    from aslam.cli.sweep_display import LiveDisplay

    shutil.copy(recordings / "good.mcap", tmp_path / "n\n\x1b[31m.mcap")
    path = tmp_path / "s.toml"
    path.write_text('[recordings]\npaths = ["*.mcap"]\n')
    sweep = read_sweep_file(path)
    [task] = plan_tasks(sweep, tmp_path / "out")
    display = LiveDisplay(Terminal(), ())
    display.result(task, TaskResult(task.index, task.key, {}, "bad\nline", (), 1.0, 1.0, "w"), False)
    screen = io.StringIO()
    Console(file=screen, width=200, force_terminal=True).print(display._render())
    [row] = [line for line in screen.getvalue().splitlines() if "n\\n" in line]
    assert "n\\n\\x1b[31m.mcap" in row and "bad\\nline" in row


def test_the_live_bar_moves_within_a_task_and_a_late_word_of_a_finished_task_is_not_counted(
    tmp_path, recordings
):
    """The bar counted finished tasks only: a sweep of a few long tasks sat at 0 for minutes. A task's
    progress event can still arrive after its result (Dask's event loop thread)."""
    from aslam.app.sweep import SweepPlan
    from aslam.cli.output import Terminal
    from aslam.cli.sweep_display import LiveDisplay

    shutil.copy(recordings / "good.mcap", tmp_path / "good.mcap")
    path = tmp_path / "s.toml"
    path.write_text('[recordings]\npaths = ["*.mcap"]\n[grid]\nbeta = [2.0, 3.0]\n')
    first, second = plan_tasks(read_sweep_file(path), tmp_path / "out")
    display = LiveDisplay(Terminal(), ())
    display.plan(SweepPlan((first, second), {}, (first, second)))

    def completed() -> float:
        return display.progress.tasks[0].completed

    display.task_progress(first, 0.25)
    display.task_progress(second, 0.5)
    assert completed() == 0.75
    display.result(first, TaskResult(0, first.key, {}, None, (), 1.0, 1.0, "w"), False)
    display.task_progress(first, 0.9)  # late: the task is done
    assert completed() == 1.5
    display.result(second, TaskResult(1, second.key, {}, None, (), 1.0, 1.0, "w"), False)
    assert completed() == 2 == display.progress.tasks[0].total


@pytest.mark.parametrize("width", [80, 120, 250])
def test_the_live_table_is_readable_at_any_terminal_width(tmp_path, recordings, width):
    """At the default figures the live table has 14 columns: at 80 columns rich folded every cell
    into strips four letters wide (``reco/rdin/g``). A table that does not fit drops its worker
    column, then becomes one line per task; every line fits the terminal, every figure is whole."""
    import io

    from rich.console import Console

    from aslam.app.sweep_file import DEFAULT_FIGURES
    from aslam.cli.output import Terminal
    from aslam.cli.sweep_display import LiveDisplay

    shutil.copy(recordings / "good.mcap", tmp_path / "good.mcap")
    path = tmp_path / "s.toml"
    path.write_text('[recordings]\npaths = ["*.mcap"]\n[grid]\nbeta = [2.0, 3.0]\n')
    first, second = plan_tasks(read_sweep_file(path), tmp_path / "out")
    screen = io.StringIO()
    terminal = Terminal()
    terminal._console = Console(file=screen, width=width)
    display = LiveDisplay(terminal, DEFAULT_FIGURES)
    summary = {key: 0.123456 for key in DEFAULT_FIGURES}
    worker = "tcp://127.0.0.1:40211"
    display.result(first, TaskResult(0, first.key, summary, None, (), 1.0, 1.0, worker), False)
    display.result(second, TaskResult(1, second.key, {}, "it broke: " + "x" * 40, (), 1.0, 1.0, "w"), False)
    terminal.console.print(display._render())
    text = screen.getvalue()
    lines = text.splitlines()
    assert all(len(line.rstrip()) <= width for line in lines)
    assert text.count("0.1235") == len(DEFAULT_FIGURES)  # every figure whole, none folded
    assert "it broke: " + "x" * 40 in text.replace("\n", "") and "good.mcap" in text
    table = lines[0].startswith("#  ")
    assert table == (width == 250)
    if not table:
        assert lines[0].startswith("#0 good.mcap beta=2.0: keyframes=0.1235")


def test_the_terminal_names_each_figure_apart_and_says_booleans_as_json_does():
    """``loop_closure.precision`` and ``committed.precision`` were both ``precision`` on a task's
    line, ``error.best.x_m.mean`` and ``error.weighted.x_m.mean`` both ``x_m.mean``; a boolean was
    Python's ``True``."""
    from aslam.app.score import summary_keys
    from aslam.app.sweep_file import DEFAULT_FIGURES
    from aslam.cli.sweep_display import figure_text, short_names

    keys = tuple(sorted(summary_keys()))
    names = short_names(keys)
    assert len(set(names)) == len(keys)
    assert all(key == name or key.endswith("." + name) for key, name in zip(keys, names, strict=True))
    picked = (
        "loop_closure.precision",
        "committed.precision",
        "error.best.x_m.mean",
        "error.weighted.x_m.mean",
    )
    assert short_names(picked) == (
        "loop_closure.precision",
        "committed.precision",
        "best.x_m.mean",
        "weighted.x_m.mean",
    )
    assert short_names(DEFAULT_FIGURES)[1:3] == ("precision", "recall")  # short where nothing else is named
    assert (figure_text(True), figure_text(False), figure_text(None)) == ("true", "false", "—")


def test_the_plan_json_replaces_no_input_and_no_file_without_force(tmp_path, capsys):
    """``--dry-run --json REC.mcap`` replaced a recording the sweep reads with its plan, in silence,
    and an existing file was replaced without ``--force``."""
    recording = write_recording(tmp_path / "rec.mcap", random_frames(3))
    before = recording.read_bytes()
    sweep = tmp_path / "s.toml"
    sweep.write_text('[recordings]\npaths = ["rec.mcap"]\n')
    dry = ["sweep", str(sweep), "-o", str(tmp_path / "out"), "--dry-run", "-q", "--json"]
    assert main([*dry, str(recording)]) == 2
    assert "resolves to an input of this command" in capsys.readouterr().err
    assert recording.read_bytes() == before
    assert main([*dry, str(tmp_path / "out" / "plan.json")]) == 2
    assert "which this sweep reads" in capsys.readouterr().err
    plan = tmp_path / "plan.json"
    assert main([*dry, str(plan)]) == 0
    assert main([*dry, str(plan)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main([*dry, str(plan), "--force"]) == 0
    assert json.loads(plan.read_text())["tasks"] == 1


def test_a_default_given_is_the_same_render(tmp_path, capsys):
    """``laps = 2`` on a preset (its default) was another render: another label, file and task."""
    sweep = tmp_path / "s.toml"
    table = '[[render]]\nroute = "paper"\nseeds = 1\nsize = "64x48"\n'
    sweep.write_text(table + "\n" + table + "laps = 2\n\n" + table.replace("paper", "grid") + "laps = 3\n")
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "out"), "--dry-run", "--json", "-", "-q"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [row["render"] for row in rows] == [
        "route=paper seed=1 size=64x48",
        "route=grid seed=1 laps=3 size=64x48",
    ]


@pytest.mark.parametrize("taken", [False, True])
def test_a_failed_sweep_removes_the_folder_it_made_unless_another_sweep_took_it(tmp_path, monkeypatch, taken):
    """A sweep refused because another took the folder while it hashed its recordings removed that
    sweep's folder, lock file and all, under it; alone, it leaves nothing."""
    import fcntl

    import aslam.app.sweep as sweep_module
    from aslam.data_formats.files import LOCK_FILE

    recording = write_recording(tmp_path / "rec.mcap", random_frames(3))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'[recordings]\npaths = ["{recording.name}"]\n')
    results = tmp_path / "out"
    other: list[int] = []

    def plan_then_fail(*_args, **_kwargs):
        if taken:  # another sweep takes the folder meanwhile (another open file: another holder)
            other.append(os.open(results / LOCK_FILE, os.O_RDWR | os.O_CREAT))
            fcntl.flock(other[0], fcntl.LOCK_EX | fcntl.LOCK_NB)
        raise InputError("a recording that cannot be read")

    monkeypatch.setattr(sweep_module, "plan_sweep", plan_then_fail)
    with pytest.raises(InputError, match="cannot be read"):
        run_sweep(read_sweep_file(sweep_file), results, workers=1)
    assert results.exists() is taken
    for descriptor in other:
        os.close(descriptor)


def test_recordings_beside_the_results_are_recordings_its_own_outputs_are_not(tmp_path, monkeypatch):
    """``-o .`` in the recordings' folder left every recording out (a sweep of no task, exit 0):
    only the sweep's own subfolders hold no recordings."""
    write_recording(tmp_path / "rec.mcap", random_frames(3))
    (tmp_path / "estimates").mkdir()
    write_recording(tmp_path / "estimates" / "old.mcap", random_frames(3, seed=1))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text('[recordings]\npaths = ["**/*.mcap"]\n')
    monkeypatch.chdir(tmp_path)
    tasks = plan_tasks(read_sweep_file(sweep_file), Path("."))
    assert [task.source.path.name for task in tasks] == ["rec.mcap"]


def test_a_sweep_refuses_listed_paths_it_cannot_read_before_running_a_task(tmp_path, capsys):
    """``paths = ["data/**"]`` planned a task for the folder itself, one for each subfolder and one for
    a README beside the recordings (the dry run listed them; the run then failed each, exit 3). The
    folders a glob passes through are no recordings; a file that is none is refused at once."""
    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    write_recording(data / "sub" / "rec.mcap", random_frames(3))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text('[recordings]\npaths = ["data/**"]\n')
    assert [task.source.path.name for task in plan_tasks(read_sweep_file(sweep_file), tmp_path / "out")] == [
        "rec.mcap"
    ]
    (data / "README.txt").write_text("recordings of the lab\n")
    with pytest.raises(ConfigError, match=r"data/README.txt: not a recording or a bag"):
        plan_tasks(read_sweep_file(sweep_file), tmp_path / "out")
    images = tmp_path / "frames"
    images.mkdir()
    cv2.imwrite(str(images / "000001.png"), np.zeros((8, 8), np.uint8))
    sweep_file.write_text('[recordings]\npaths = ["data/**/*.mcap", "frames"]\n')
    dry = ["sweep", str(sweep_file), "-o", str(tmp_path / "out"), "--dry-run", "-q"]
    assert main(dry) == 2
    err = capsys.readouterr().err
    assert "frames: is an image folder; make it a recording first: aslam import" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_a_task_whose_recording_was_replaced_since_the_plan_fails_rather_than_saving_other_bytes(
    tmp_path,
):
    """A recording replaced mid-sweep (``mv new R.mcap``) was estimated by the tasks that ran after,
    their results saved under the planned file's hash: wrong rows, reused by every later run even
    after the file was put back. A task now checks the bytes it read against the plan's hash."""
    from aslam.app.sweep import run_task

    recording = write_recording(tmp_path / "R.mcap", random_frames(3))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text('[recordings]\npaths = ["R.mcap"]\n')
    [task] = plan_tasks(read_sweep_file(sweep_file), tmp_path / "out")
    assert run_task(task).ok
    write_recording(tmp_path / "other.mcap", random_frames(4, seed=5))
    os.replace(tmp_path / "other.mcap", recording)
    result = run_task(task)
    assert not result.ok and result.summary is None
    assert f"{recording}: not the bytes the sweep planned this task with" in result.error
    # Replaced between the estimate and the scoring: the truth came from the other file.
    recording.unlink()
    write_recording(recording, random_frames(3))
    [task] = plan_tasks(read_sweep_file(sweep_file), tmp_path / "out")
    import aslam.app.score as score_module

    real_score = score_module.score

    def replaced_first(*args, **kwargs):
        write_recording(tmp_path / "other.mcap", random_frames(4, seed=5))
        os.replace(tmp_path / "other.mcap", recording)
        return real_score(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(score_module, "score", replaced_first)
        result = run_task(task)
    assert not result.ok and "not the bytes the sweep planned" in result.error


def test_a_render_the_recorder_would_refuse_is_refused_with_the_sweep_file(tmp_path):
    """The file check missed what ``aslam record`` refuses only once it builds the route: the dry
    run planned these renders and the run failed every one (exit 3 after starting a cluster).
    Now each is a problem of the sweep file (exit 2), with the rest, before any work."""
    (tmp_path / "open.json").write_text('{"actions": [{"forward_m": 2}]}')
    (tmp_path / "odd.json").write_text('{"actions": [{"forward_m": 1}], "colour": "red"}')
    renders = [
        "camera_height_m = 2.4",
        "camera_height_m = 0.01",
        "odometry_reset_at = 69",
        "laps = 5000",
        'route = "open.json"\nlaps = 2',
        'route = "odd.json"',
        "noise = 1" + "0" * 400,
    ]
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text("".join(f'[[render]]\nsize = "64x48"\n{r}\n\n' for r in renders))
    with pytest.raises(ConfigError) as info:
        read_sweep_file(sweep_file)
    message = str(info.value)
    for number, needle in enumerate(
        [
            "camera_height_m must be below 2.4 m",
            "camera_height_m must be at least 0.1 m",
            "odometry_reset_at must be a keyframe of the route (0..68), got 69",
            "for 170,000 actions; at most 100,000",
            "so laps 2 cannot repeat it",
            "unknown key(s) 'colour'",
            "noise must be a number a float can hold",
        ],
        start=1,
    ):
        assert f"render #{number}: " in message and needle in message, needle


def test_a_dry_run_waits_for_no_scheduler_file(tmp_path, capsys, monkeypatch):
    """A dry run contacts no scheduler: with a scheduler file not yet written it waited 30 s, then
    exit 2. It still refuses what the run would (--workers beside a cluster's file)."""

    def never(_path):
        raise AssertionError("a dry run read the scheduler file")

    monkeypatch.setattr("aslam.app.sweep.scheduler_address", never)
    recording = write_recording(tmp_path / "rec.mcap", random_frames(3))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'[recordings]\npaths = ["{recording.name}"]\n')
    dry = ["sweep", str(sweep_file), "-o", str(tmp_path / "out"), "--dry-run", "-q"]
    later = ["--scheduler-file", str(tmp_path / "not-yet.json")]
    assert main([*dry, *later]) == 0
    assert main([*dry, *later, "--workers", "2"]) == 2
    assert "--workers sizes a local cluster" in capsys.readouterr().err


def test_a_run_removes_what_a_killed_worker_was_writing(tmp_path, monkeypatch):
    """A worker killed mid-task (its task run again on another) left its partial estimate until the
    next run began in the folder."""
    import aslam.app.sweep as sweep_module
    from aslam.data_formats.files import PARTIAL_MARK

    recording = write_recording(tmp_path / "rec.mcap", random_frames(3))
    sweep_file = tmp_path / "s.toml"
    sweep_file.write_text(f'[recordings]\npaths = ["{recording.name}"]\n')
    results = tmp_path / "out"
    gone = subprocess.Popen(["true"])  # a process id that no longer runs
    gone.wait()
    left = results / "estimates" / f".x.mcap{PARTIAL_MARK}{gone.pid}"
    compute = sweep_module._compute

    def killed_worker_then_compute(*args, **kwargs):
        left.parent.mkdir(parents=True, exist_ok=True)
        left.write_bytes(b"half an estimate")
        return compute(*args, **kwargs)

    monkeypatch.setattr(sweep_module, "_compute", killed_worker_then_compute)
    run = run_sweep(read_sweep_file(sweep_file), results, workers=1)
    run.check()
    assert not left.exists()


def test_renders_that_differ_in_a_knob_read_apart():
    """The plan, the live lines and the Pareto table named renders by route and seed alone: the
    example file's aliasing 0.5 and 1.0 renders of seed 1 read alike."""
    from aslam.app.sweep import Source

    labels = {
        Source(Path(f"r{a}.mcap"), "id", "r.mcap", RecordConfig(seed=1, aliasing=a)).label for a in (0.5, 1.0)
    }
    assert labels == {
        "render route=paper seed=1 aliasing=0.5 (r.mcap)",
        "render route=paper seed=1 aliasing=1 (r.mcap)",
    }


def test_a_rows_error_names_the_topic_keys_as_the_sweep_file_spells_them():
    """A bag read with /tf odometry whose frames are not there failed its row saying to give
    ``--odom-frame`` (``aslam estimate``'s option); in a sweep file it is ``odom_frame``."""
    from aslam.app.sweep import in_sweep_words

    said = "name the frames (--odom-frame, --base-frame) or an odometry topic (--odometry-topic)"
    assert in_sweep_words(said) == (
        "name the frames (odom_frame, base_frame) or an odometry topic (odometry_topic)"
    )
    assert in_sweep_words("no image topic; name one with --image-topic") == (
        "no image topic; name one with image_topic"
    )
    # an option standing alone only: a path or a topic may hold one in its name
    named = "/data/run--image-topic-test/bag.mcap: no transform on '/robot--base-frame/tf'"
    assert in_sweep_words(named) == named
    assert in_sweep_words("(--ground-truth-topic of estimate or report)") == (
        "(ground_truth_topic in the sweep file's [recordings])"
    )


def test_a_bag_swept_with_its_topics_named_is_scored(tmp_path, capsys):
    """``[recordings]`` takes ``aslam estimate``'s topic options (with underscores) for the bags it
    lists: a bag's ground truth is read only from a named topic, so a sweep over real bags could not
    score a row (and a bag that needs ``--image-topic`` failed every one). A bad value is told with
    the file's other problems."""
    from conftest import square_route, write_square_bag

    write_square_bag(tmp_path / "bag.mcap", square_route(), seed=1, ground_truth_topic="/truth")
    sweep = tmp_path / "s.toml"
    figures = 'figures = ["loop_closure.precision", "loop_closure.recall"]\n'
    sweep.write_text(figures + '[recordings]\npaths = ["bag.mcap"]\nground_truth_topic = "/truth"\n')
    assert [r.topics.ground_truth for r in read_sweep_file(sweep).recordings] == ["/truth"]
    assert main(["sweep", str(sweep), "-o", str(tmp_path / "scored"), "--workers", "1", "-q"]) == 0
    scored = _rows(tmp_path / "scored")
    assert [r["status"] for r in scored] == ["ok"]
    assert scored[0]["loop_closure.precision"] is not None and scored[0]["loop_closure.recall"] > 0
    assert scored[0]["topics"] == "ground_truth_topic=/truth"
    # Bags of two robots, each table with its own topics: one file under two sets is two recordings.
    both = tmp_path / "both.toml"
    both.write_text(
        '[[recordings]]\npaths = ["bag.mcap"]\n'
        '[[recordings]]\npaths = ["bag.mcap", "bag.mcap"]\nground_truth_topic = "/truth"\n'
    )
    tasks = plan_tasks(read_sweep_file(both), tmp_path / "both")
    assert [(t.source.label, t.source.topics.ground_truth) for t in tasks] == [
        ("bag.mcap", None),
        ("bag.mcap (ground_truth_topic=/truth)", "/truth"),
    ]
    assert tasks[0].key != tasks[1].key
    unnamed = tmp_path / "unnamed.toml"  # the same task without the key, run here (no cluster)
    unnamed.write_text(figures + '[recordings]\npaths = ["bag.mcap"]\n')
    (task,) = plan_tasks(read_sweep_file(unnamed), tmp_path / "unscored")
    unscored = run_task(task)
    assert unscored.ok and unscored.summary is not None
    assert unscored.summary["loop_closure.precision"] is None
    # ... and says which key would score it, as the sweep file spells it (it named report's option)
    assert [w for w in unscored.warnings if "ground-truth topic" in w] == [
        f"{tmp_path / 'bag.mcap'}: no ground-truth topic named for this bag"
        " (ground_truth_topic in the sweep file's [recordings]); reporting without ground truth"
    ]
    # A topic the bag does not have is told when the sweep is planned (the dry run), from the bag's
    # index: it failed every row of its bags after the others ran.
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(figures + '[recordings]\npaths = ["bag.mcap"]\nimage_topic = "/no_camera"\n')
    with pytest.raises(ConfigError, match=r"bag.mcap: no image topic '/no_camera' \(topics in the bag: "):
        plan_tasks(read_sweep_file(wrong), tmp_path / "failed")
    capsys.readouterr()
    bad = tmp_path / "bad.toml"
    bad.write_text('[recordings]\npaths = ["bag.mcap"]\nimage_topic = 5\nodometry_topic = " /odom"\n')
    assert main(["sweep", str(bad), "-o", str(tmp_path / "none"), "--dry-run"]) == 2
    name = "must be a topic or frame name (a string without spaces), got"
    assert one_error_line(capsys.readouterr().err) == (
        f"aslam: error: {bad}: recordings.image_topic {name} 5; recordings.odometry_topic {name} ' /odom'"
    )
    # One table of several forgot its paths: its robot's bags were left out in silence.
    forgot = tmp_path / "forgot.toml"
    forgot.write_text('[[recordings]]\npaths = ["bag.mcap"]\n[[recordings]]\nimage_topic = "/cam"\n')
    assert main(["sweep", str(forgot), "-o", str(tmp_path / "none"), "--dry-run"]) == 2
    assert one_error_line(capsys.readouterr().err) == (
        f"aslam: error: {forgot}: recordings #2: paths: none (a table's topic keys apply to the files"
        " its paths name)"
    )


def test_the_terminal_spells_a_tasks_parameters_as_the_sweep_file_does(recordings, tmp_path):
    """`paper_faithful=True` (Python's spelling) on the terminal, where the sweep file wrote `true`."""
    from aslam.cli.sweep_display import parameters_text

    sweep = tmp_path / "s.toml"
    sweep.write_text(
        f'figures = ["keyframes"]\n[recordings]\npaths = ["{recordings / "good.mcap"}"]\n'
        "[[grid]]\npaper_faithful = [true, false]\nthumbnail_beta = 8.0\n"
    )
    texts = [parameters_text(task) for task in plan_tasks(read_sweep_file(sweep), tmp_path / "out")]
    assert texts == ["paper_faithful=true thumbnail_beta=8.0", "paper_faithful=false thumbnail_beta=8.0"]
