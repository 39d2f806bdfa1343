"""`aslam sweep` on a local cluster against the same tasks run one after another.

20 tasks: 2 rendered recordings (paper route, 2 laps, 320×240, seeds 0 and 1; cached in
bench/.cache/sweep/) × 10 parameter sets (beta 2..4 × cells_x 1, 2). Each task is an estimate and
a score.

one_core    the tasks one after another in a fresh process with no Dask in it, one thread each
            (reader and descriptions in the calling thread, as a sweep task runs): "one thing after
            another on one core", the baseline the target is set against;
serial      the same loop with ``estimate``'s defaults, as ``aslam estimate`` runs: a forked reader
            process and two threads decoding and describing images, so it already uses ~1.35 cores;
sweep       ``run_sweep`` on a LocalCluster of N worker processes started beforehand, the task
            modules imported on each (the tasks' time: plan, submit, last result, tables);
sweep_cold  ``run_sweep`` starting and stopping its own LocalCluster, once (the whole command).

The serial loops run in their own process, after their imports, while no cluster runs: Dask's
scheduler and idle workers would otherwise take CPU from them. Runs alternate (one_core, serial,
sweep, ...) so that other load on a shared machine falls on each alike; ratios are per repeat
(median, min, max). CPU seconds are reported too (serial: the process and its reader children;
sweep: the workers' CPU during their tasks): on a shared machine wall-clock ratios say as much
about the neighbours' load as about the sweep. The figures of every run are checked to be equal.

    python bench/sweep_bench.py [--workers 2] [--repeats 5]     # prints JSON on stdout
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from measure import spread

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


def serial_loop(mode: str, folder: Path) -> dict:
    """The tasks one after another in this process (run as ``--serial MODE``, a process of its own)."""
    options = {"workers": 0, "reader_process": False} if mode == "one_core" else {}
    tasks = plan_tasks(read_sweep_file(CACHE / "sweep.toml"), folder / "plan")
    figures = []
    start, cpu_start = time.perf_counter(), _cpu_s()
    for task in tasks:
        output = folder / f"{task.key[:16]}.mcap"
        estimate(task.source.path, output, task.config, force=True, **options)
        report = score(output, recording=task.source.path)
        figures.append(_figures(report.summary))
    return {"seconds": time.perf_counter() - start, "cpu_s": _cpu_s() - cpu_start, "figures": figures}


def run_serial(mode: str, folder: Path) -> tuple[float, float, list[dict]]:
    folder.mkdir()
    done = subprocess.run(
        [sys.executable, __file__, "--serial", mode, "--folder", str(folder)],
        check=True,
        capture_output=True,
        text=True,
    )
    result = json.loads(done.stdout)
    return result["seconds"], result["cpu_s"], result["figures"]


def _import_task_modules() -> None:
    """What a worker imports for its first task, done before the clock starts (as in the serial loops)."""
    import aslam.app.estimate
    import aslam.app.score  # noqa: F401


def run_parallel(sweep, folder: Path, workers: int) -> tuple[float, float, list[dict]]:
    """Wall seconds, the workers' CPU seconds spent in the tasks, and the figures."""
    client = open_client(workers=workers, scheduler=None)
    try:
        client.wait_for_workers(workers)
        client.run(_import_task_modules)
        start = time.perf_counter()
        run = run_sweep(sweep, folder, client=client, force=True)
        seconds = time.perf_counter() - start
    finally:
        client.close()
        client.cluster.close()
    cpu = sum(r.task_cpu_s or 0.0 for r in run.results)
    return seconds, cpu, [_sweep_figures(r) for r in run.results]


def _sweep_figures(result) -> dict:
    return {k: v for k, v in result.summary.items() if not k.startswith("timing.")}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--serial", choices=("one_core", "serial"), help=argparse.SUPPRESS)
    parser.add_argument("--folder", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serial:
        print(json.dumps(serial_loop(args.serial, args.folder)))
        return
    sweep = read_sweep_file(recordings())
    times: dict[str, list[float]] = {"one_core": [], "serial": [], "sweep": []}
    cpu: dict[str, list[float]] = {name: [] for name in times}
    identical = True
    reference = None
    with tempfile.TemporaryDirectory(prefix="aslam-sweep-bench-") as tmp:
        folder = Path(tmp)
        for repeat in range(args.repeats):
            for name in times:
                out = folder / f"{name}-{repeat}"
                if name == "sweep":
                    seconds, cpu_s, figures = run_parallel(sweep, out, args.workers)
                else:
                    seconds, cpu_s, figures = run_serial(name, out)
                reference = reference or figures
                identical = identical and figures == reference
                times[name].append(seconds)
                cpu[name].append(cpu_s)
                print(f"{name} #{repeat}: {seconds:.2f} s wall, {cpu_s:.2f} s CPU", file=sys.stderr)
        cold_start = time.perf_counter()
        cold = run_sweep(sweep, folder / "cold", workers=args.workers, force=True)
        cold_s = time.perf_counter() - cold_start
        identical = identical and [_sweep_figures(r) for r in cold.results] == reference
    ratios = {
        f"{name}_over_sweep": [s / p for s, p in zip(times[name], times["sweep"], strict=True)]
        for name in ("one_core", "serial")
    }
    print(
        json.dumps(
            {
                "tasks": len(reference or []),
                "workers": args.workers,
                "repeats": args.repeats,
                "seconds": {name: spread(values) for name, values in times.items()},
                "cpu_seconds": {name: spread(values) for name, values in cpu.items()},
                "sweep_cold_s": cold_s,
                "ratio": {name: spread(values) for name, values in ratios.items()},
                "target_one_core_over_sweep": 1.7,
                "identical_figures": identical,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
