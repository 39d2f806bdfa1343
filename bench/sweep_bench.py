"""`aslam sweep` on a local cluster against the same tasks run serially, in one process.

20 tasks: 2 rendered recordings (paper route, 2 laps, 320×240, seeds 0 and 1; cached in
bench/.cache/sweep/) × 10 parameter sets (beta 2..4 × cells_x 1, 2). Each task is an estimate and
a score.

serial           the tasks one after another in this process, calling ``estimate`` (with its
                 defaults: a forked reader process and two histogram threads, as ``aslam estimate``
                 runs) then ``score``;
serial_inproc    the same with the task's own settings (reader in-process, one histogram thread):
                 what one sweep task costs on one core;
sweep            ``run_sweep`` on a LocalCluster of N worker processes started beforehand (the
                 tasks' time: submit to last result);
sweep_cold       ``run_sweep`` starting and stopping its own LocalCluster, once (the whole command).

CPU seconds are reported too (serial: this process and its reader children; sweep: the workers'
CPU during their tasks): on a machine shared with other work, wall-clock ratios say as much about
the others' load as about the sweep (with Linux's autogroup scheduling, one session's processes
share one session's CPU share, so two worker processes there need not get twice the CPU of one),
while CPU per task shows the sweep's own overhead.

Runs alternate (serial, serial_inproc, sweep, ...) so that other load on a shared machine falls on
each alike; the ratios are reported per repeat (median, min, max). Target: serial / sweep ≥ 1.7
with 2 workers on 2 cores. The figures of every sweep run are checked against the serial ones.

    python bench/sweep_bench.py [--workers 2] [--repeats 3]     # prints JSON on stdout
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

from aslam.app.estimate import estimate
from aslam.app.score import leaves, score
from aslam.app.sweep import open_client, plan_tasks, run_sweep
from aslam.app.sweep_file import read_sweep_file
from aslam.recorder.config import RecordConfig
from aslam.recorder.record import record

CACHE = Path(__file__).resolve().parent / ".cache" / "sweep"
SEEDS = (0, 1)
SWEEP = """
figures = ["keyframes", "loop_closure.precision", "loop_closure.recall", "error.best.x_m.mean"]
[recordings]
paths = ["seed0.mcap", "seed1.mcap"]
[grid]
beta = [2.0, 2.5, 3.0, 3.5, 4.0]
cells_x = [1, 2]
"""


def recordings() -> Path:
    CACHE.mkdir(parents=True, exist_ok=True)
    for seed in SEEDS:
        path = CACHE / f"seed{seed}.mcap"
        if not path.exists():
            print(f"rendering {path.name} (once) ...", file=sys.stderr)
            record(RecordConfig(route="paper", laps=2, seed=seed), path)
    sweep_file = CACHE / "sweep.toml"
    sweep_file.write_text(SWEEP)
    return sweep_file


def _figures(summary: dict) -> dict:
    return {k: v for k, v in leaves(summary).items() if not k.startswith("timing.")}


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (the forked reader of ``estimate``)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def run_serial(tasks, folder: Path, *, task_settings: bool) -> tuple[float, float, list[dict]]:
    options = {"workers": 1, "reader_process": False} if task_settings else {}
    figures = []
    start, cpu_start = time.perf_counter(), _cpu_s()
    for task in tasks:
        output = folder / f"{task.key[:16]}.mcap"
        estimate(task.source.path, output, task.config, force=True, **options)
        report = score(output, recording=task.source.path)
        figures.append(_figures(report.summary))
    return time.perf_counter() - start, _cpu_s() - cpu_start, figures


def run_parallel(sweep, folder: Path, client) -> tuple[float, float, list[dict]]:
    """Wall seconds, the workers' CPU seconds spent in the tasks, and the figures."""
    start = time.perf_counter()
    run = run_sweep(sweep, folder, client=client, force=True)
    seconds = time.perf_counter() - start
    cpu = sum(r.task_cpu_s or 0.0 for r in run.results)
    return (
        seconds,
        cpu,
        [{k: v for k, v in r.summary.items() if not k.startswith("timing.")} for r in run.results],
    )


def spread(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sweep = read_sweep_file(recordings())
    with tempfile.TemporaryDirectory(prefix="aslam-sweep-bench-") as tmp:
        folder = Path(tmp)
        tasks = plan_tasks(sweep, folder / "plan")
        times: dict[str, list[float]] = {"serial": [], "serial_inproc": [], "sweep": []}
        cpu: dict[str, list[float]] = {name: [] for name in times}
        identical = True
        reference = None
        client = open_client(workers=args.workers, scheduler=None)
        try:
            client.wait_for_workers(args.workers)
            for repeat in range(args.repeats):
                for name in times:
                    out = folder / f"{name}-{repeat}"
                    out.mkdir()
                    if name == "sweep":
                        seconds, cpu_s, figures = run_parallel(sweep, out, client)
                    else:
                        seconds, cpu_s, figures = run_serial(
                            tasks, out, task_settings=name == "serial_inproc"
                        )
                    reference = reference or figures
                    identical = identical and figures == reference
                    times[name].append(seconds)
                    cpu[name].append(cpu_s)
                    print(f"{name} #{repeat}: {seconds:.2f} s wall, {cpu_s:.2f} s CPU", file=sys.stderr)
        finally:
            client.close()
            client.cluster.close()
        cold_start = time.perf_counter()
        cold = run_sweep(sweep, folder / "cold", workers=args.workers, force=True)
        cold_s = time.perf_counter() - cold_start
        identical = (
            identical
            and [{k: v for k, v in r.summary.items() if not k.startswith("timing.")} for r in cold.results]
            == reference
        )
    ratios = {
        f"{name}_over_sweep": [s / p for s, p in zip(times[name], times["sweep"], strict=True)]
        for name in ("serial", "serial_inproc")
    }
    print(
        json.dumps(
            {
                "tasks": len(tasks),
                "workers": args.workers,
                "repeats": args.repeats,
                "seconds": {name: spread(values) for name, values in times.items()},
                "cpu_seconds": {name: spread(values) for name, values in cpu.items()},
                "sweep_cold_s": cold_s,
                "ratio": {name: spread(values) for name, values in ratios.items()},
                "target_serial_over_sweep": 1.7,
                "identical_figures": identical,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
