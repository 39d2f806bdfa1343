"""`make bench`: every benchmark in one run; regenerates docs/benchmarks.md and docs/img/*.png.

    python bench/run_all.py [--quick] [--doc docs/benchmarks.md] [--img docs/img]

1. Scenarios recorded with ``aslam record`` (cached in bench/.cache/), each run through
   ``aslam estimate`` (project defaults and ``--paper-faithful``) and ``aslam report --json -``,
   and through the baselines of ``bench/baselines.py`` (odometry only, nearest neighbour), all
   scored by ``aslam.core.metrics.evaluate``.
2. Speed and scaling: ``bench/estimate_bench.py``, ``bench/slam_scaling_bench.py``,
   ``bench/record_bench.py`` in subprocesses (``--json``), ratios measured within one run.
3. The document, written from scratch with the figures of this run.

``--quick`` (two seeds, shorter runs, no 100,000-keyframe run) is for trying the script; it
writes to bench/.cache/quick/ unless --doc/--img are given.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import contextlib

import baselines
import scenarios
from scenarios import ROOT, Scenario

from aslam.core.config import EstimatorConfig
from aslam.core.metrics import Evaluation, evaluate, true_runs
from aslam.data_formats.report import build_summary

BENCH = ROOT / "bench"
SEEDS = (1, 2, 3, 4, 5)
NOISES = (0.01, 0.03, 0.05, 0.10)
SCALING_BIG = 100_000
SCALING_FALLBACK = 50_000
SCALING_BIG_TIMEOUT_S = 330
SCALING_REPEATS = 3
METHODS = ("aslam", "paper-faithful", "nearest", "odometry")
METHOD_NAMES = {
    "aslam": "aslam (defaults)",
    "paper-faithful": "aslam `--paper-faithful`",
    "nearest": "nearest neighbour",
    "odometry": "odometry only",
}


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


# --- running the scenarios -------------------------------------------------------------------------


@dataclass
class Run:
    """One scenario: its recording, the four methods' summaries and what the tables need besides."""

    scenario: Scenario
    keyframes: int = 0
    true_revisits: int = 0
    record_s: float | None = None
    summaries: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Summary JSON per method (the estimator's from ``aslam report --json -``)."""
    lap2: dict[str, float | None] = field(default_factory=dict)
    f1: dict[str, float] = field(default_factory=dict)
    peak_rss_mib: dict[str, float] = field(default_factory=dict)
    wall_s: dict[str, float] = field(default_factory=dict)
    drift: baselines.Drift | None = None
    evaluations: dict[str, Evaluation] = field(default_factory=dict)
    mismatch: list[str] = field(default_factory=list)
    nearest_wrong_recent: int = 0
    """Wrong nearest-neighbour claims that named one of the 3 keyframes just before."""


def second_lap_accuracy(evaluation: Evaluation, scenario: Scenario) -> float | None:
    start = scenario.second_lap_from
    if start is None or evaluation.keyframes <= start:
        return None
    return float(evaluation.correct[start:].mean())


def run_scenario(
    scenario: Scenario,
    threshold: float,
    work: Path,
    plots: dict[str, Path] | None = None,
) -> Run:
    """Record (or take from the cache), estimate with both settings, report, and run the baselines."""
    path, record_s = scenarios.recording(scenario, log=log)
    run = Run(scenario, record_s=record_s)
    keyframes = baselines.read_keyframes(path)
    run.keyframes = len(keyframes.stamps_ns)
    for method in ("aslam", "paper-faithful"):
        estimate = work / f"{scenario.short_name}-{method}.mcap"
        plot_dir = (plots or {}).get(method)
        result = scenarios.estimate_and_report(path, estimate, scenario, method, plots=plot_dir)
        summary = result["summary"]
        run.summaries[method] = summary
        run.peak_rss_mib[method] = result["peak_rss_mib"]
        run.wall_s[method] = result["wall_s"]
        steps = scenarios.estimate_steps(estimate)
        evaluation = evaluate(steps, keyframes.true_poses)
        run.evaluations[method] = evaluation
        run.lap2[method] = second_lap_accuracy(evaluation, scenario)
        run.f1[method] = baselines.f1(evaluation)
        # The report and this bench must agree (same keyframes, same ground truth, same scoring).
        if len(steps) != run.keyframes or summary["loop_closure"]["precision"] != evaluation.precision:
            run.mismatch.append(
                f"{method}: report says {summary['keyframes']} keyframes, precision "
                f"{summary['loop_closure']['precision']}; bench {run.keyframes}, {evaluation.precision}"
            )
        estimate.unlink()
    matches = baselines.nearest_neighbours(keyframes.histograms)
    nearest = baselines.nearest_neighbour(keyframes, threshold, matches)
    wrong = nearest.claims & ~nearest.correct
    t = np.flatnonzero(wrong)
    run.nearest_wrong_recent = int((t - matches[0][t] <= 3).sum())
    odometry = baselines.odometry_only(keyframes)
    for method, evaluation in (("nearest", nearest), ("odometry", odometry)):
        states = int((~evaluation.claims).sum())
        run.summaries[method] = build_summary(evaluation, states=states, links=0, keyframes_per_second=None)
        run.evaluations[method] = evaluation
        run.lap2[method] = second_lap_accuracy(evaluation, scenario)
        run.f1[method] = baselines.f1(evaluation)
    run.true_revisits = int(odometry.true_revisit.sum())
    run.drift = baselines.odometry_drift(keyframes)
    return run


def tuned_threshold(scenario: Scenario) -> dict[str, Any]:
    path, _ = scenarios.recording(scenario, log=log)
    keyframes = baselines.read_keyframes(path)
    threshold, evaluation = baselines.tune_threshold(keyframes)
    return {
        "threshold": threshold,
        "precision": evaluation.precision,
        "recall": evaluation.recall,
        "f1": baselines.f1(evaluation),
    }


# --- speed benches ---------------------------------------------------------------------------------


def bench_json(script: str, *args: str, timeout: float | None = None) -> dict[str, Any]:
    command = [sys.executable, str(BENCH / script), *args, "--json"]
    log(f"  {' '.join(command[1:])}")
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    if result.returncode != 0:
        raise SystemExit(f"{script} failed ({result.returncode}):\n{result.stderr[-3000:]}")
    data = json.loads(result.stdout.strip().splitlines()[-1])
    data["bench_wall_s"] = time.perf_counter() - start
    data["command"] = "python bench/" + script + " " + " ".join(a for a in args)
    return data


def slam_profile(recording: Path) -> dict[str, float]:
    """Share of the SLAM step's time per tree method (cumulative), from cProfile over a recording."""
    import cProfile
    import pstats

    from aslam.core.estimator import Estimator

    keyframes = baselines.read_keyframes(recording)
    profiler = cProfile.Profile()
    estimator = Estimator()
    profiler.enable()
    for i, stamp in enumerate(keyframes.stamps_ns):
        estimator.add_keyframe(stamp, keyframes.actions[i], keyframes.histograms[i])
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in stats.values())  # sum of tottime = profiled time
    shares: dict[str, float] = {}
    for (filename, _, name), (_, _, _, cumtime, _) in stats.items():
        if filename.endswith("tree.py") and name in (
            "_search",
            "_search_path",
            "_prune",
            "_commit",
            "_propose",
        ):
            shares[name] = max(shares.get(name, 0.0), cumtime / total)
    return shares


def speed_benches(quick: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    repeats = "2" if quick else "3"
    for laps in (4, 10):
        scenario = Scenario("speed", "paper", laps, 1, fps=3)
        path, _ = scenarios.recording(scenario, log=log)
        data = bench_json("estimate_bench.py", "--recording", str(path), "--repeats", repeats)
        data["command"] = (
            f"python bench/estimate_bench.py --recording {scenario.command().split()[-1]} --repeats {repeats}"
            f"  # {scenario.command()}"
        )
        out[f"estimate_laps{laps}"] = data
        if laps == 10:
            data["profile"] = slam_profile(path)
    keyframes = "2000" if quick else "10000"
    for world in ("blocks", "random"):
        # Three runs of each world: the ratio of two 1,000-keyframe windows moves by
        # ±0.1 with the machine's load, so the median is reported and judged, with the range.
        trials = []
        for _ in range(SCALING_REPEATS):
            trials.append(bench_json("slam_scaling_bench.py", "--keyframes", keyframes, "--world", world))
        ratios = sorted(r["ratio_last_over_first"] for r in trials)
        median = sorted(trials, key=lambda r: r["ratio_last_over_first"])[len(trials) // 2]
        out[f"scaling_{world}"] = median | {"ratios": ratios}
    big = 5_000 if quick else SCALING_BIG
    try:
        out["scaling_big"] = bench_json(
            "slam_scaling_bench.py",
            "--keyframes",
            str(big),
            "--world",
            "blocks",
            timeout=SCALING_BIG_TIMEOUT_S,
        )
        out["scaling_big"]["fallback"] = False
    except subprocess.TimeoutExpired:
        log(f"  {big} keyframes took over {SCALING_BIG_TIMEOUT_S} s; running {SCALING_FALLBACK} instead")
        out["scaling_big"] = bench_json(
            "slam_scaling_bench.py", "--keyframes", str(SCALING_FALLBACK), "--world", "blocks"
        )
        out["scaling_big"]["fallback"] = True
        out["scaling_big"]["attempted"] = big
    out["record"] = bench_json("record_bench.py", "--repeats", repeats)
    return out


# --- the machine -----------------------------------------------------------------------------------


def machine() -> dict[str, str]:
    info: dict[str, str] = {}
    cpuinfo = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    models = [line.split(":", 1)[1].strip() for line in cpuinfo.splitlines() if line.startswith("model name")]
    info["CPU"] = models[0] if models else platform.processor() or "unknown"
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    info["cores"] = f"{usable} usable ({os.cpu_count()} online)"
    meminfo = Path("/proc/meminfo").read_text() if Path("/proc/meminfo").exists() else ""
    for line in meminfo.splitlines():
        if line.startswith("MemTotal:"):
            info["RAM"] = f"{int(line.split()[1]) / 2**20:.1f} GiB"
    info["OS"] = f"{platform.system()} {platform.release()} ({platform.machine()})"
    info["Python"] = platform.python_version()
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "from aslam.recorder.render import select_platform\n"
            "p = select_platform()\n"
            "import pyrender\n"
            "r = pyrender.OffscreenRenderer(8, 8)\n"
            "from OpenGL.GL import GL_RENDERER, GL_VERSION, glGetString\n"
            "print(p, '|', glGetString(GL_RENDERER).decode(), '|', glGetString(GL_VERSION).decode())\n"
            "r.delete()\n",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    info["OpenGL"] = probe.stdout.strip().replace("|", "·") if probe.returncode == 0 else "probe failed"
    versions = []
    for package in (
        "aslam",
        "numpy",
        "opencv-python-headless",
        "pyrender",
        "PyOpenGL",
        "trimesh",
        "mcap",
        "mcap-ros2-support",
        "matplotlib",
        "typer",
        "rich",
    ):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            versions.append(f"{package} {importlib.metadata.version(package)}")
    info["packages"] = ", ".join(versions)
    git = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain"], capture_output=True, text=True)
    if git.returncode == 0:
        info["commit"] = git.stdout.strip() + (" + uncommitted changes" if dirty.stdout.strip() else "")
    return info


def load_average() -> str:
    try:
        return ", ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


# --- plots ---------------------------------------------------------------------------------------


def drift_plot(run: Run, path: Path) -> None:
    """Odometry drift against the estimator's best-hypothesis error, per keyframe (long run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    assert run.drift is not None
    evaluation = run.evaluations["aslam"]
    t = np.arange(run.keyframes)
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.plot(t, run.drift.position_m, color="tab:red", lw=1.2, label="odometry only: |odometry − truth|")
    best = np.hypot(evaluation.best_error[:, 0], evaluation.best_error[:, 1])
    ax.plot(t, best, ".", ms=2, color="tab:blue", label="aslam best hypothesis: revisit position error")
    ax.set_xlabel("keyframe")
    ax.set_ylabel("position error (m)")
    ax.set_ylim(bottom=0)
    ax.set_title(f"{run.scenario.short_name}: what the error grows to without loop closure")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- formatting ------------------------------------------------------------------------------------


def fmt(value: float | None, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "—"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def agg(values: list[float | None], digits: int = 2, what_none: str = "n/a") -> str:
    """mean (min–max) over seeds; values that are None are counted, not averaged."""
    present = [float(v) for v in values if v is not None and np.isfinite(v)]
    missing = len(values) - len(present)
    if not present:
        return "—" if what_none == "n/a" else f"{what_none} ×{missing}"
    lo, hi, mean = min(present), max(present), float(np.mean(present))
    text = fmt(mean, digits)
    if len(present) > 1 and fmt(lo, digits) != fmt(hi, digits):
        text += f" ({fmt(lo, digits)}–{fmt(hi, digits)})"
    if missing:
        text += f", {what_none} ×{missing}"
    return text


def get(summary: dict[str, Any], dotted: str) -> Any:
    value: Any = summary
    for key in dotted.split("."):
        value = value[key]
    return value


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def loop_closing_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    rows = []
    for method in METHODS:
        s = [r.summaries[method] for r in runs]
        never = "never"
        row = [METHOD_NAMES[method]] if label is None else [label, METHOD_NAMES[method]]
        row += [
            agg([get(x, "relocalisation.first_delay_keyframes") for x in s], 1, never),
            agg([get(x, "relocalisation.mean_delay_keyframes") for x in s], 1, never),
            agg([get(x, "loop_closure.precision") for x in s], 2, "no claims"),
            agg([get(x, "loop_closure.recall") for x in s]),
            agg([r.f1[method] for r in runs]),
            str(
                sum(int((r.evaluations[method].claims & ~r.evaluations[method].correct).sum()) for r in runs)
            ),
            str(
                sum(
                    int((r.evaluations[method].true_revisit & ~r.evaluations[method].correct).sum())
                    for r in runs
                )
            ),
        ]
        if any(r.scenario.second_lap_from is not None for r in runs):
            row.append(agg([r.lap2[method] for r in runs]))
        rows.append(row)
    return rows


def loop_closing_header(runs: list[Run], label: str | None = None) -> list[str]:
    header = [] if label is None else [label]
    header += [
        "method",
        "first delay (kf)",
        "mean delay (kf)",
        "precision",
        "recall",
        "F1",
        "wrong claims (all runs)",
        "missed revisits (all runs)",
    ]
    if any(r.scenario.second_lap_from is not None for r in runs):
        header.append("2nd-lap accuracy")
    return header


def error_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    """Rows per method and kind (best, belief-weighted): x, y, heading error mean / max."""
    rows = []

    def cells(stats: list[dict[str, dict[str, float | None]]]) -> list[str]:
        out = []
        for axis in ("x_m", "y_m", "heading_deg"):
            digits = 1 if axis == "heading_deg" else 2
            mean = agg([s[axis]["mean"] for s in stats], digits)
            high = agg([s[axis]["max"] for s in stats], digits)
            out.append(f"{mean} / {high}")
        return out

    for method in METHODS:
        prefix = [METHOD_NAMES[method]] if label is None else [label, METHOD_NAMES[method]]
        if method == "odometry":
            stats = [r.drift.axis_stats() for r in runs if r.drift is not None]
            rows.append([*prefix, "odometry − truth", *cells(stats)])  # type: ignore[arg-type]
            continue
        kinds = ("best",) if method == "nearest" else ("best", "weighted")
        for kind in kinds:
            stats = [r.summaries[method]["error"][kind] for r in runs]
            name = (
                "best (the only hypothesis)"
                if method == "nearest"
                else kind.replace("weighted", "belief-weighted")
            )
            rows.append([*prefix, name, *cells(stats)])
    return rows


def error_header(label: str | None = None) -> list[str]:
    header = [] if label is None else [label]
    return [
        *header,
        "method",
        "hypothesis",
        "x error mean / max (m)",
        "y error mean / max (m)",
        "heading error mean / max (°)",
    ]


def cost_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    rows = []
    for method in ("aslam", "paper-faithful"):
        row = [METHOD_NAMES[method]] if label is None else [label, METHOD_NAMES[method]]
        s = [r.summaries[method] for r in runs]
        row += [
            agg([get(x, "states") for x in s], 0),
            agg([get(x, "hypotheses.max") for x in s], 0),
            agg([get(x, "hypotheses.mean") for x in s], 1),
            agg([get(x, "timing.keyframes_per_second") for x in s], 0),
            agg([r.wall_s[method] for r in runs], 2),
            agg([r.peak_rss_mib[method] for r in runs], 0),
        ]
        rows.append(row)
    return rows


def cost_header(label: str | None = None) -> list[str]:
    header = [] if label is None else [label]
    return [
        *header,
        "method",
        "states",
        "hypotheses max",
        "hypotheses mean",
        "keyframes/s",
        "`aslam estimate` wall (s)",
        "peak RSS (MiB)",
    ]


def drift_line(runs: list[Run]) -> str:
    drifts = [r.drift for r in runs if r.drift is not None]
    return (
        "Odometry alone (keyframe actions composed from the first true pose) ends "
        f"{agg([d.final_m for d in drifts])} m from the truth, at worst "
        f"{agg([d.max_m for d in drifts])} m, and its heading is off by up to "
        f"{agg([d.max_heading_deg for d in drifts], 1)}°."
    )


def first_delays(runs: list[Run], method: str) -> str:
    return agg([get(r.summaries[method], "relocalisation.first_delay_keyframes") for r in runs], 1, "never")


def mean_of(runs: list[Run], method: str, dotted: str) -> float | None:
    values = [get(r.summaries[method], dotted) for r in runs]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def mean_attr(runs: list[Run], name: str, method: str) -> float | None:
    values = [getattr(r, name)[method] for r in runs]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


# --- the document ----------------------------------------------------------------------------------


def compare_sentence(runs: list[Run], family: str) -> str:
    """Which method closed loops best in this family, in numbers."""
    parts = []
    for method in ("aslam", "paper-faithful", "nearest"):
        p = mean_of(runs, method, "loop_closure.precision")
        r = mean_of(runs, method, "loop_closure.recall")
        parts.append(f"{METHOD_NAMES[method]} P {fmt(p)} / R {fmt(r)}")
    f1s = {m: mean_attr(runs, "f1", m) or 0.0 for m in ("aslam", "paper-faithful", "nearest")}
    winner = max(f1s, key=lambda m: f1s[m])
    margin = f1s["aslam"] - f1s["nearest"]
    if abs(margin) < 0.02:
        verdict = (
            f"On {family} the tree and the nearest-neighbour baseline are level on F1 "
            f"({f1s['aslam']:.2f} vs {f1s['nearest']:.2f}): here the hypothesis tree does not earn its keep "
            "in loop-closure terms."
        )
    elif margin > 0:
        verdict = (
            f"On {family} the tree beats the nearest-neighbour baseline on F1 by {margin:.2f} "
            f"({f1s['aslam']:.2f} vs {f1s['nearest']:.2f})."
        )
    else:
        verdict = (
            f"On {family} the nearest-neighbour baseline beats the tree on F1 by {-margin:.2f} "
            f"({f1s['nearest']:.2f} vs {f1s['aslam']:.2f})."
        )
    return f"{verdict} Best F1: {METHOD_NAMES[winner]}. Means over the runs: " + "; ".join(parts) + "."


def write_doc(
    path: Path,
    img: Path,
    *,
    started: datetime.datetime,
    total_s: float,
    info: dict[str, str],
    loads: tuple[str, str],
    families: dict[str, list[Run]],
    noise_runs: dict[float, list[Run]],
    tuning: dict[str, Any],
    speed: dict[str, Any],
    images: dict[str, str],
    quick: bool,
) -> None:
    rel = os.path.relpath(img, path.parent)
    out: list[str] = []
    w = out.append
    paper, aliasing = families["paper"], families["aliasing"]
    routes, long_run = families["routes"], families["long"]
    seeds = ", ".join(str(r.scenario.seed) for r in paper)
    minutes, seconds = divmod(round(total_s), 60)

    w("# Benchmarks\n")
    w(
        f"_Generated by `make bench` (`bench/run_all.py`) on {started:%Y-%m-%d %H:%M %Z}; the whole run took "
        f"{minutes} min {seconds:02d} s. Every figure, table and plot below comes from that one run: do not "
        "edit this file by hand, rerun `make bench`._"
        + (" **Quick mode (`--quick`): fewer seeds and shorter runs.**" if quick else "")
        + "\n"
    )
    w(
        "Benchmarks live in `bench/`, print figures and ratios measured in one run, and never run as "
        "timed assertions in the test suite (the machine is shared and noisy: only ratios measured "
        "side by side in the same run are compared with targets).\n"
    )

    # --- machine
    w("## Machine\n")
    rows = [[k, v] for k, v in info.items()]
    rows.append(["load average (1, 5, 15 min)", f"at start {loads[0]}; at end {loads[1]}"])
    w(table(["", ""], rows) + "\n")

    # --- commands
    w("## Commands\n")
    w("```sh\nmake bench   # = .venv/bin/python bench/run_all.py  (not part of CI)\n```\n")
    w(
        "It records every scenario once with `aslam record` (cached in `bench/.cache/record-<hash>/`, "
        "the hash covering the recorder's and the recording format's source; delete the folder to "
        "re-render), then per recording:\n"
    )
    w(
        "```sh\n"
        "aslam estimate REC.mcap -o EST.mcap --odometry-noise σ                    # project defaults\n"
        "aslam estimate REC.mcap -o EST.mcap --odometry-noise σ --paper-faithful   # the paper's estimator\n"
        "aslam report EST.mcap --json -                                            # the scores below\n"
        "```\n"
    )
    w(
        "Each `aslam estimate` runs in its own process; its peak memory is the maximum resident set "
        "of that process and its forked reader (`wait4`), Python and every import included. The "
        "baselines (`bench/baselines.py`) read the same recordings with the estimator's own keyframe "
        "test and histograms and are scored by the same `aslam.core.metrics.evaluate` (and "
        "`build_summary`) as `aslam report`. Then the speed benches, each a subprocess:\n"
    )
    w("```sh")
    for key in (
        "estimate_laps4",
        "estimate_laps10",
        "scaling_blocks",
        "scaling_random",
        "scaling_big",
        "record",
    ):
        w(speed[key]["command"])
    w("```\n")
    w("Recordings (320×240, all seeds fixed):\n")
    families_rows = [
        [
            "paper route",
            paper[0].scenario.command().replace(f"--seed {paper[0].scenario.seed}", "--seed S"),
            seeds,
        ],
        [
            "noise sweep",
            noise_runs[NOISES[0]][0]
            .scenario.command()
            .replace(f"--seed {noise_runs[NOISES[0]][0].scenario.seed}", "--seed S")
            .replace(f"--noise {NOISES[0]:g}", "--noise σ"),
            f"{seeds}; σ = " + ", ".join(f"{n:g}" for n in NOISES) + " (σ = 0.03 is the paper route above)",
        ],
        [
            "perceptual aliasing",
            aliasing[0].scenario.command().replace(f"--seed {aliasing[0].scenario.seed}", "--seed S"),
            seeds,
        ],
    ]
    families_rows += [
        [f"{r.scenario.route} route", r.scenario.command(), str(r.scenario.seed)] for r in routes
    ]
    families_rows += [["long run", r.scenario.command(), str(r.scenario.seed)] for r in long_run]
    w(table(["scenario", "command", "seeds"], [[a, f"`{b}`", c] for a, b, c in families_rows]) + "\n")

    # --- how to read
    w("## How to read the tables\n")
    w(
        "- **Methods.** *aslam (defaults)*: `EstimatorConfig()` (spatial cells 2×1, graph search of "
        "the map). *aslam `--paper-faithful`*: `EstimatorConfig.paper_faithful()`, the paper's "
        "estimator (one global histogram per image, revisit candidates only along the hypothesis's "
        "own path). *nearest neighbour*: the same histograms as the defaults (16 bins, 2×1 cells); at "
        "each keyframe it claims the earlier keyframe with the smallest χ² if that χ² is below "
        f"**{tuning['threshold']:.4f}**, else a new place: one hypothesis, no tree, no motion model. "
        f"That threshold is the one that maximises its F1 on seed {tuning['seed']} of the paper route "
        f"(there: precision {fmt(tuning['precision'])}, recall {fmt(tuning['recall'])}, F1 "
        f"{fmt(tuning['f1'])}); it is used unchanged on every other recording. *odometry only*: never "
        "claims a revisit; its error columns are the dead-reckoned odometry against ground truth "
        "(|odometry − truth| per axis, mean / max over keyframes), i.e. what the error grows to "
        "without loop closure.\n"
        "- **Delay** (keyframes): a relocalisation episode is a run of keyframes that truly revisit "
        "a place; its delay is the keyframes from its start until the best hypothesis names a "
        "correct state. *First* is the first episode (the start of the second lap on the paper "
        "route), *mean* over all episodes that relocalised; *never* counts runs where it did not.\n"
        "- **Precision / recall** of the best hypothesis's revisit claims: a claim is correct when "
        "the true positions are within 0.5 m and 45°; recall is over keyframes that truly revisit. "
        "F1 = 2PR/(P+R), 0 without claims.\n"
        f"- **2nd-lap accuracy** (paper route only): fraction of keyframes from {scenarios.PAPER_LAP} on "
        "(the second lap) whose best hypothesis names a correct state.\n"
        '- **Errors** (as the paper\'s figures 9–11): for a hypothesis saying "revisit of state k", '
        "true pose now − true pose at k's first visit, absolute; best hypothesis (mean / max over the "
        "keyframes where it claims a revisit) and the belief-weighted mean over revisit hypotheses "
        "(its max shown). An error is only counted where a revisit is claimed, so a method that "
        "claims little can show small errors: read errors together with recall.\n"
        "- Five-seed families show **mean (min–max) over seeds**.\n"
    )
    w(
        "**Ground truth in these recordings.** The recorder keeps the true path on the commanded "
        "route (plus ~5 cm / 1.5° jitter per keyframe, not accumulated) and puts the 3 % error into "
        "the odometry only. A true path accumulating 3 % would drift about 1 m per 30 m lap, leave "
        "the 2 m corridor, and only ~55 % of lap-2 keyframes would still be real revisits "
        '(`docs/recorder.md`, "Noise model"). So here every lap-2 keyframe of the paper route is a '
        "real revisit of a lap-1 place, and the estimator is scored against that; the paper's robot "
        "really drifted, which is one reason its delays and ours are not the same experiment.\n"
    )

    # --- paper route
    w(f"## Paper route: 10 m × 5 m rectangle, 2 laps, 3 % odometry noise, seeds {seeds}\n")
    w(
        f"{paper[0].keyframes} keyframes per run ({scenarios.PAPER_LAP} per lap + the start), of which "
        f"{agg([r.true_revisits for r in paper], 0)} are true revisits. {drift_line(paper)}\n"
    )
    w("Loop closing:\n")
    w(table(loop_closing_header(paper), loop_closing_rows(paper)) + "\n")
    w("Revisit errors (odometry-only row: odometry − truth):\n")
    w(table(error_header(), error_rows(paper)) + "\n")
    w("Cost (the estimator; the baselines reuse the histograms and cost next to nothing):\n")
    w(table(cost_header(), cost_rows(paper)) + "\n")
    w("Per seed, project defaults:\n")
    rows = []
    for r in paper:
        s = r.summaries["aslam"]
        rows.append(
            [
                str(r.scenario.seed),
                str(s["keyframes"]),
                str(s["loop_closure"]["ground_truth_revisits"]),
                f"{s['loop_closure']['claims']} / {s['loop_closure']['correct']}",
                fmt(s["loop_closure"]["precision"]),
                fmt(s["loop_closure"]["recall"]),
                fmt(s["relocalisation"]["first_delay_keyframes"]),
                fmt(s["relocalisation"]["mean_delay_keyframes"], 1),
                fmt(r.lap2["aslam"]),
                f"{s['hypotheses']['max']} / {s['hypotheses']['mean']:.1f}",
                fmt(r.summaries["paper-faithful"]["loop_closure"]["recall"]),
                fmt(r.lap2["paper-faithful"]),
                f"{r.drift.final_m:.2f} / {r.drift.max_m:.2f}" if r.drift else "—",
            ]
        )
    w(
        table(
            [
                "seed",
                "keyframes",
                "true revisits",
                "claims / correct",
                "precision",
                "recall",
                "first delay",
                "mean delay",
                "2nd-lap acc.",
                "hyp. max / mean",
                "paper-faithful recall",
                "paper-faithful 2nd-lap acc.",
                "odometry drift final / max (m)",
            ],
            rows,
        )
        + "\n"
    )
    for r in paper + aliasing + routes + long_run:
        for line in r.mismatch:
            w(f"> **Report and bench disagree** on {r.scenario.name}: {line}\n")

    # --- against the paper
    seed1 = paper[0]
    w(f"### Against the paper (seed {seed1.scenario.seed}, project defaults)\n")
    w(
        f"![hypotheses over time]({rel}/{images['hypotheses']})\n\n"
        f"![x, y and heading error over time]({rel}/{images['errors']})\n\n"
        f"![map]({rel}/{images['map']})\n"
    )
    paper_comparison(w, paper, seeds)

    # --- noise sweep
    w("## Noise sweep: paper route, odometry noise σ = " + ", ".join(f"{n:g}" for n in NOISES) + "\n")
    w(
        f"Seeds {seeds} at each level; the estimator is told the same σ (`--odometry-noise σ`). "
        "Means over seeds (min–max).\n"
    )
    rows = []
    for noise in NOISES:
        runs = noise_runs[noise]
        drifts = [r.drift for r in runs if r.drift is not None]
        block = loop_closing_rows(runs, f"{noise:g}")
        block[0].append(f"{agg([d.final_m for d in drifts])} / {agg([d.max_m for d in drifts])}")
        for row in block[1:]:
            row.append("")
        rows += block
    header = [*loop_closing_header(noise_runs[NOISES[0]], "σ"), "odometry drift final / max (m)"]
    w(table(header, rows) + "\n")

    # --- aliasing
    w(f"## Perceptual aliasing: paper route, `--aliasing 0.5`, seeds {seeds}\n")
    w(
        "Half the wall panels are drawn from 3 shared textures, so distinct places look alike. "
        f"{drift_line(aliasing)}\n"
    )
    w(table(loop_closing_header(aliasing), loop_closing_rows(aliasing)) + "\n")
    w(table(error_header(), error_rows(aliasing)) + "\n")
    w(table(cost_header(), cost_rows(aliasing)) + "\n")
    if "aliasing_hypotheses" in images:
        w(
            f"![hypotheses over time, aliasing 0.5, seed {aliasing[0].scenario.seed}]"
            f"({rel}/{images['aliasing_hypotheses']})\n"
        )

    # --- routes
    w("## Other routes: figure 8 and grid, 3 laps\n")
    for r in routes:
        w(
            f"- **{r.scenario.route}** (seed {r.scenario.seed}): {r.keyframes} keyframes, "
            f"{r.true_revisits} true revisits. {drift_line([r])}"
        )
    w("")
    rows, err_rows, c_rows = [], [], []
    for r in routes:
        rows += loop_closing_rows([r], r.scenario.route)
        err_rows += error_rows([r], r.scenario.route)
        c_rows += cost_rows([r], r.scenario.route)
    w(table(loop_closing_header(routes, "route"), rows) + "\n")
    w(table(error_header("route"), err_rows) + "\n")
    w(table(cost_header("route"), c_rows) + "\n")

    # --- long run
    lr = long_run[0]
    w(f"## Long run: {lr.scenario.route} route, {lr.scenario.laps} laps, {lr.keyframes} keyframes\n")
    w(f"{lr.true_revisits} true revisits. {drift_line([lr])}\n")
    w(table(loop_closing_header(long_run), loop_closing_rows(long_run)) + "\n")
    w(table(error_header(), error_rows(long_run)) + "\n")
    w(table(cost_header(), cost_rows(long_run)) + "\n")
    if "drift" in images:
        w(f"![odometry drift against the estimator's error, long run]({rel}/{images['drift']})\n")

    # --- speed
    write_speed(w, speed, paper)

    # --- reading
    write_reading(w, families, noise_runs, speed, tuning)
    path.write_text("\n".join(out).rstrip() + "\n")


def spans(mask: np.ndarray) -> str:
    """'38–43, 50–52' for the runs of True in ``mask``."""
    out = [str(start) if stop - 1 == start else f"{start}–{stop - 1}" for start, stop in true_runs(mask)]
    return ", ".join(out) if out else "nowhere"


def paper_comparison(w, paper: list[Run], seeds: str) -> None:
    """The paper's figures 8–11 in words, and ours beside them (seed 1, project defaults)."""
    seed1 = paper[0]
    s1 = seed1.summaries["aslam"]
    e1 = seed1.evaluations["aslam"]
    lap = scenarios.PAPER_LAP
    first = s1["relocalisation"]["first_delay_keyframes"]
    w(
        "**The paper** (its figure 8, the number of path hypotheses over the run): the robot starts "
        'the second cycle at t = 36 and "localizes itself again at t = 50 and t = 72", i.e. 14 '
        "keyframes after the revisits begin. Its figures 9–11 (x, y and heading error): the path "
        "hypotheses are kept close to the true robot position; several hypotheses can coexist, but "
        'the low error says they agree on where the robot is. We read "localizes itself" as our '
        "relocalisation delay: keyframes until the best hypothesis names a correct state.\n"
    )
    where = (
        "**never** in the first episode"
        if first is None
        else f"at keyframe {lap + first}, i.e. **{first} keyframes** after the revisits begin"
    )
    best = s1["error"]["best"]
    lap2 = seed1.lap2["aslam"]
    text = (
        f"**We measure** (seed {seed1.scenario.seed}): the second lap starts at keyframe {lap}; the best "
        f"hypothesis names a correct state {where} (over seeds {seeds}: first delay "
        f"{first_delays(paper, 'aslam')} keyframes; `--paper-faithful`: "
        f"{first_delays(paper, 'paper-faithful')}). The hypothesis plot shows "
        + (
            "one hypothesis through the first lap and "
            if int(e1.hypothesis_counts[:lap].max(initial=1)) == 1
            else f"up to {int(e1.hypothesis_counts[:lap].max())} hypotheses in the first lap and "
        )
        + "more than one at keyframes "
        f"{spans(e1.hypothesis_counts > 1)} (at most {s1['hypotheses']['max']}, mean "
        f"{s1['hypotheses']['mean']:.1f}; "
        + (
            f"back to one from keyframe {int(np.flatnonzero(e1.hypothesis_counts > 1)[-1]) + 1} on"
            if (e1.hypothesis_counts > 1).any() and e1.hypothesis_counts[-1] == 1
            else f"{int(e1.hypothesis_counts[-1])} at the end"
        )
        + "); the best hypothesis claims a revisit at "
        f"{int(e1.claims.sum())} keyframes, {int(e1.correct.sum())} of them correct, and "
        f"{fmt(lap2 * 100 if lap2 is not None else None, 0)} % of the second lap's keyframes name a correct "
        f"state. In the error plot the best hypothesis's revisit errors stay within "
        f"{fmt(best['x_m']['max'])} m in x, {fmt(best['y_m']['max'])} m in y and "
        f"{fmt(best['heading_deg']['max'], 1)}° in heading (means {fmt(best['x_m']['mean'])} m, "
        f"{fmt(best['y_m']['mean'])} m, {fmt(best['heading_deg']['mean'], 1)}°)"
    )
    if best["x_m"]["max"] is not None and max(best["x_m"]["max"], best["y_m"]["max"]) <= 0.25:
        text += (
            ": no larger than the two visits' own ground-truth jitter (σ = 5 cm and 1.5° per visit), "
            "so, as in the paper, the revisits it names are the places it is at"
        )
    if seed1.drift is not None:
        text += (
            f". Odometry alone is {seed1.drift.final_m:.2f} m off by the end of the run (at worst "
            f"{seed1.drift.max_m:.2f} m)."
        )
    w(text + "\n")
    delays = [r.summaries["aslam"]["relocalisation"]["first_delay_keyframes"] for r in paper]
    faithful = [r.summaries["paper-faithful"]["relocalisation"]["first_delay_keyframes"] for r in paper]
    if all(d is not None and d < 14 for d in delays + faithful):
        w(
            "**Why we re-localise sooner than the paper's 14 keyframes**, with the paper's own "
            'estimator (`--paper-faithful`) too: (1) our ground truth does not drift (see "Ground '
            'truth in these recordings"), so the second lap retraces the first within centimetres and '
            "the views match closely, whereas the paper's robot came back some decimetres off its "
            "first-lap path; (2) rendered, evenly lit walls with a distinct texture per panel give "
            "cleaner histogram matches than the paper's real corridor. A short delay here says that "
            "this route, rendered, leaves the estimator little to disambiguate; it does not say the "
            "estimator would beat the paper's 14 keyframes on the paper's data. The aliasing family "
            "below is the harder test.\n"
        )
    else:
        w(
            "Some runs re-localise as late as the paper or later (first delays above); see the per-seed "
            'table. Our ground truth does not drift (see "Ground truth in these recordings"), so the '
            "comparison is with an easier version of the paper's experiment.\n"
        )


def _near_target(goal: str, measured: str) -> bool:
    """A ratio target missed by less than 5 % ("≤ 1.25" against "1.257")."""
    try:
        target = float(goal.split()[-1])
        value = float(measured.split()[0])
    except ValueError:
        return False
    return goal.startswith("≤") and value <= target * 1.05


def write_speed(w, speed: dict[str, Any], paper: list[Run]) -> None:
    w("## Speed and scaling\n")
    w("All ratios below are measured side by side within this run; absolute times vary with the load.\n")
    w("### Estimate against its floor (`bench/estimate_bench.py`)\n")
    w(
        "floor = the same pipeline without SLAM (read the MCAP, keyframe test, decode keyframe images, "
        "histograms); estimate = the estimate command's body in-process (pipeline + SLAM + estimate "
        "file + hashing). Alternating runs, best of each. Target: estimate ≤ 1.25 × floor. For the "
        "reader, two parts of the difference timed alone on the same recording: the SLAM steps "
        "(`Estimator.add_keyframe` over precomputed histograms, one thread) and the SHA-256 of the "
        "recording that identifies it in the estimate file (a background thread in `aslam estimate`).\n"
    )
    rows = []
    for key, label in (
        ("estimate_laps4", "paper route, 4 laps, 3 fps"),
        ("estimate_laps10", "paper route, 10 laps, 3 fps"),
    ):
        d = speed[key]
        rows.append(
            [
                label,
                f"{d['size_mb']:.1f}",
                str(d["keyframes"]),
                f"{d['floor_s']:.3f}",
                f"{d['estimate_s']:.3f}",
                f"**{d['ratio']:.3f}**",
                "met" if d["ratio"] <= 1.25 else "**not met**",
                f"{d['keyframes_per_second']:.0f}",
                f"{d['estimate_s'] - d['floor_s']:.3f}",
                f"{d['slam_only_s']:.3f} ({d['slam_only_s'] / d['keyframes'] * 1e3:.2f} ms/kf)",
                f"{d['sha256_s']:.3f}",
            ]
        )
    w(
        table(
            [
                "recording",
                "MB",
                "keyframes",
                "floor (s)",
                "estimate (s)",
                "ratio",
                "≤ 1.25",
                "keyframes/s",
                "estimate − floor (s)",
                "SLAM steps alone (s)",
                "SHA-256 alone (s)",
            ],
            rows,
        )
        + "\n"
    )
    w("### SLAM step against map size (`bench/slam_scaling_bench.py`)\n")
    w(
        "Synthetic walks without images (1 m steps, 90° turns, 3 % odometry noise; a random histogram per "
        "place and heading, each view a noisy copy). *blocks*: twice round each city block, then on to "
        "the next: the map grows for ever at constant density. *random*: a random walk on a 20 m × 20 m "
        "grid: the map saturates and its links grow denser. Ratio = mean `add_keyframe` time over the "
        "last 1,000 keyframes ÷ the first 1,000 (target ≤ 1.3); the 10,000-keyframe runs are made "
        f"{SCALING_REPEATS} times each and the median run is shown (the ratio of two 1,000-keyframe windows "
        "moves with the machine's load). Peak RSS of the whole process (target < 1 GiB).\n"
    )
    rows = []
    for key in ("scaling_blocks", "scaling_random", "scaling_big"):
        d = speed[key]
        rows.append(
            [
                d["world"],
                f"{d['keyframes']:,}",
                f"{d['states']:,}",
                f"{d['first_ms']:.3f}",
                f"{d['last_ms']:.3f}",
                f"**{d['ratio_last_over_first']:.2f}**"
                + (
                    f" (median of {len(d['ratios'])}: " + ", ".join(f"{x:.2f}" for x in d["ratios"]) + ")"
                    if "ratios" in d
                    else ""
                ),
                "met" if d["ratio_last_over_first"] <= 1.3 else "**not met**",
                f"{d['hypotheses_mean']:.2f} / {d['hypotheses_max']}",
                f"{d['searched_states_mean']:.0f}",
                f"{d['peak_rss_mib']:.0f}",
                f"{d['bench_wall_s']:.0f}",
            ]
        )
    w(
        table(
            [
                "world",
                "keyframes",
                "states",
                "first 1,000 (ms/kf)",
                "last 1,000 (ms/kf)",
                "ratio",
                "≤ 1.3",
                "hypotheses mean / max",
                "states searched / kf",
                "peak RSS (MiB)",
                "wall (s)",
            ],
            rows,
        )
        + "\n"
    )
    big = speed["scaling_big"]
    if big.get("fallback"):
        w(
            f"The {big['attempted']:,}-keyframe run took longer than {SCALING_BIG_TIMEOUT_S} s and was "
            f"stopped; the table shows {big['keyframes']:,} keyframes instead.\n"
        )
    w(
        f"Peak memory at {big['keyframes']:,} keyframes: **{big['peak_rss_mib']:.0f} MiB** "
        f"({'met' if big['peak_rss_mib'] < 1024 else '**not met**'}: target < 1 GiB).\n"
    )
    d = speed["record"]
    w("### Recording speed (`bench/record_bench.py`)\n")
    w(
        f"Paper route, {d['laps']} laps = {d['keyframes']} keyframes at {d['size']}, best of {d['repeats']}, "
        "alternating the two loops so they share whatever else the machine is doing:\n\n"
        "- **record end-to-end**: `aslam.recorder.record.record()` from config to a finished MCAP "
        "(world generation, GL context, shader compilation, rendering, PNG encoding, writing);\n"
        "- **record loop**: its render → encode → write loop alone;\n"
        "- **bare pyrender loop**: the same scene and poses with nothing but `scene.set_pose(camera)` and "
        "`renderer.render(scene)`.\n\n"
        "Targets: ≥ 30 keyframes/s at 320×240, and the record loop ≤ 1.3 × the bare loop.\n"
    )
    w(
        table(
            [
                "record end-to-end",
                "record loop",
                "bare pyrender loop",
                "loop ratio",
                "end-to-end ratio",
            ],
            [
                [
                    f"{d['end_to_end_keyframes_per_second']:.1f} keyframes/s",
                    f"{d['loop_keyframes_per_second']:.1f} keyframes/s",
                    f"{d['bare_keyframes_per_second']:.1f} keyframes/s",
                    f"**{d['ratio_loop_over_bare']:.2f}**",
                    f"{d['ratio_end_to_end_over_bare']:.2f}",
                ]
            ],
        )
        + "\n"
    )


def blocks_note(speed: dict[str, Any]) -> str:
    """Whether the blocks world's cost still grows between the 10,000 and the long run."""
    small, big = speed["scaling_blocks"], speed["scaling_big"]
    if big["keyframes"] <= small["keyframes"]:
        return "the cost per keyframe grows with the map; the graph search and the commit are the suspects."
    growth = big["last_ms"] / small["last_ms"]
    return (
        f"the states searched per keyframe average {big['searched_states_mean']:.0f} (the "
        f"`search_max_states` cap is {EstimatorConfig().search_max_states}), and the last 1,000 keyframes "
        f"cost {small['last_ms']:.3f} ms each after {small['keyframes']:,} keyframes and "
        f"{big['last_ms']:.3f} ms after {big['keyframes']:,} ({growth:.2f}×, separate processes of this "
        "run): "
        + (
            "the cost stops growing once the map outgrows the search's reach, and the ratio mostly says "
            "the first 1,000 keyframes are cheaper, while the map within reach is still small. A "
            "steady-state window (e.g. keyframes 1,000–2,000) as the reference would measure the "
            "scaling the target is about."
            if growth < 1.1
            else "the cost keeps growing with the map; the graph search and the commit are the suspects."
        )
    )


def write_reading(w, families, noise_runs, speed, tuning) -> None:
    paper, aliasing, routes, long_run = (
        families["paper"],
        families["aliasing"],
        families["routes"],
        families["long"],
    )
    w("## Targets\n")
    rec = speed["record"]
    big = speed["scaling_big"]
    rows = [
        [
            "estimate ÷ floor, paper route 4 laps",
            "≤ 1.25",
            f"{speed['estimate_laps4']['ratio']:.3f}",
            speed["estimate_laps4"]["ratio"] <= 1.25,
        ],
        [
            "estimate ÷ floor, paper route 10 laps",
            "≤ 1.25",
            f"{speed['estimate_laps10']['ratio']:.3f}",
            speed["estimate_laps10"]["ratio"] <= 1.25,
        ],
        [
            f"SLAM step, last ÷ first 1,000, blocks ({speed['scaling_blocks']['keyframes']:,})",
            "≤ 1.3",
            f"{speed['scaling_blocks']['ratio_last_over_first']:.2f}",
            speed["scaling_blocks"]["ratio_last_over_first"] <= 1.3,
        ],
        [
            f"SLAM step, last ÷ first 1,000, random ({speed['scaling_random']['keyframes']:,})",
            "≤ 1.3",
            f"{speed['scaling_random']['ratio_last_over_first']:.2f}",
            speed["scaling_random"]["ratio_last_over_first"] <= 1.3,
        ],
        [
            f"SLAM step, last ÷ first 1,000, blocks ({big['keyframes']:,})",
            "≤ 1.3",
            f"{big['ratio_last_over_first']:.2f}",
            big["ratio_last_over_first"] <= 1.3,
        ],
        [
            f"peak memory, {big['keyframes']:,} keyframes",
            "< 1 GiB",
            f"{big['peak_rss_mib']:.0f} MiB",
            big["peak_rss_mib"] < 1024,
        ],
        [
            "record, keyframes/s (record loop / end-to-end)",
            "≥ 30",
            f"{rec['loop_keyframes_per_second']:.1f} / {rec['end_to_end_keyframes_per_second']:.1f}",
            rec["loop_keyframes_per_second"] >= 30,
        ],
        [
            "record loop ÷ bare pyrender loop",
            "≤ 1.3",
            f"{rec['ratio_loop_over_bare']:.2f}",
            rec["ratio_loop_over_bare"] <= 1.3,
        ],
    ]
    w(
        table(
            ["target", "goal", "measured", "met"],
            [[a, b, c, "yes" if ok else "**no**"] for a, b, c, ok in rows],
        )
        + "\n"
    )
    missed = [r for r in rows if not r[3]]

    w("## Reading\n")
    everything = paper + aliasing + routes + long_run

    def wrong(runs: list[Run], method: str) -> int:
        return sum(int((r.evaluations[method].claims & ~r.evaluations[method].correct).sum()) for r in runs)

    def missed_revisits(runs: list[Run], method: str) -> int:
        return sum(
            int((r.evaluations[method].true_revisit & ~r.evaluations[method].correct).sum()) for r in runs
        )

    p_aslam = mean_of(paper, "aslam", "loop_closure.precision")
    r_aslam = mean_of(paper, "aslam", "loop_closure.recall")
    lap2 = mean_attr(paper, "lap2", "aslam")
    recent = sum(r.nearest_wrong_recent for r in paper)
    w(
        f"- **Paper route.** With the project's defaults the estimator closes the loop with precision "
        f"{fmt(p_aslam)} and recall {fmt(r_aslam)} (means over seeds), first delay "
        f"{first_delays(paper, 'aslam')} keyframes and {fmt(lap2 * 100 if lap2 is not None else None, 0)} % "
        "second-lap accuracy. "
        + compare_sentence(paper, "the paper route")
        + f" Over the {len(paper)} seeds the nearest neighbour makes {wrong(paper, 'nearest')} wrong claims "
        f"({recent} of them naming one of the 3 keyframes just before, a view of the same corridor a step "
        f"back) and leaves {missed_revisits(paper, 'nearest')} true revisits unrecognised; the tree makes "
        f"{wrong(paper, 'aslam')} wrong claims and misses {missed_revisits(paper, 'aslam')}. A single χ² "
        "threshold has to trade one against the other; the tree accepts a weaker match when the motion "
        "model can reach that place and refuses a strong one it cannot.\n"
    )
    hyp_alias = [r.summaries["aslam"]["hypotheses"]["max"] for r in aliasing]
    hyp_paper = [r.summaries["aslam"]["hypotheses"]["max"] for r in paper]
    nn_far = max(
        float(np.nanmax(np.hypot(e[:, 0], e[:, 1]), initial=0.0))
        for e in (r.evaluations["nearest"].best_error for r in aliasing)
    )
    w(
        "- **Perceptual aliasing (0.5).** "
        + compare_sentence(aliasing, "the aliased paper route")
        + f" Wrong claims over the {len(aliasing)} seeds: tree {wrong(aliasing, 'aslam')}, "
        f"`--paper-faithful` {wrong(aliasing, 'paper-faithful')}, nearest neighbour "
        f"{wrong(aliasing, 'nearest')}"
        + (
            f" (its worst claim names a place {nn_far:.1f} m away: a look-alike panel elsewhere)"
            if nn_far > 1.0
            else ""
        )
        + f". The tree's hypothesis count: max {agg(hyp_alias, 0)}, against {agg(hyp_paper, 0)} "
        "without aliasing"
        + (
            ": the motion-model gate removes most look-alike candidates before they become "
            "hypotheses, so the branching is rarely exercised.\n"
            if max(hyp_alias) <= 3
            else ": the tree carries the look-alike candidates until later views decide.\n"
        )
    )
    all_max = max(r.summaries["aslam"]["hypotheses"]["max"] for r in everything)
    all_mean = max(r.summaries["aslam"]["hypotheses"]["mean"] for r in everything)
    pf_max = max(r.summaries["paper-faithful"]["hypotheses"]["max"] for r in everything)
    margins = {
        "paper route": (mean_attr(paper, "f1", "aslam") or 0) - (mean_attr(paper, "f1", "nearest") or 0),
        "aliasing": (mean_attr(aliasing, "f1", "aslam") or 0) - (mean_attr(aliasing, "f1", "nearest") or 0),
    }
    for r in routes + long_run:
        margins[f"{r.scenario.route} ×{r.scenario.laps}"] = r.f1["aslam"] - r.f1["nearest"]
    earns = [f"{k} ({v:+.2f})" for k, v in margins.items() if v >= 0.02]
    level = [f"{k} ({v:+.2f})" for k, v in margins.items() if v < 0.02]
    w(
        "- **Where the hypothesis tree earns its keep.** F1 of the defaults minus the nearest "
        "neighbour's: "
        + (", ".join(earns) if earns else "nowhere by 0.02 or more")
        + (
            "; level or behind: " + ", ".join(level) + "."
            if level
            else "; it is not level or behind anywhere in this run."
        )
        + f" With the defaults the tree never holds more than {all_max} hypotheses in any run (mean per "
        f"run at most {all_mean:.1f}), so on these recordings the gain comes mostly from the motion model "
        "and the map search that decide which candidates are reachable, not from carrying many "
        f"alternatives; `--paper-faithful` branches more (up to {pf_max}) because a single global "
        "histogram leaves more places looking alike.\n"
    )
    pf_gap = (mean_attr(paper, "f1", "aslam") or 0) - (mean_attr(paper, "f1", "paper-faithful") or 0)
    al_gap = (mean_attr(aliasing, "f1", "aslam") or 0) - (mean_attr(aliasing, "f1", "paper-faithful") or 0)
    w(
        f"- **Defaults against `--paper-faithful`.** F1 difference (defaults − paper-faithful): "
        f"{pf_gap:+.2f} on the paper route, {al_gap:+.2f} with aliasing"
        + "".join(
            f", {(r.f1['aslam'] - r.f1['paper-faithful']):+.2f} on {r.scenario.route} ×{r.scenario.laps}"
            for r in routes + long_run
        )
        + ". Spatial cells keep *where* the edges are, which separates places a single global "
        "histogram confuses; the map search finds a revisit through earlier loop closures rather than "
        "only along the hypothesis's own path, which matters on routes that cross themselves (figure 8, "
        "grid).\n"
    )
    noise_bits = []
    for noise in NOISES:
        runs = noise_runs[noise]
        noise_bits.append(
            f"σ = {noise:g}: F1 {fmt(mean_attr(runs, 'f1', 'aslam'))} (paper-faithful "
            f"{fmt(mean_attr(runs, 'f1', 'paper-faithful'))}), odometry drift up to "
            f"{fmt(float(np.mean([r.drift.max_m for r in runs if r.drift])))} m"
        )
    w(
        "- **Noise.** "
        + "; ".join(noise_bits)
        + ". The images do not depend on σ (only the odometry does), so the nearest neighbour's rows "
        "are the same at every level; the estimator is told σ and its gate widens with it.\n"
    )
    for r in routes + long_run:
        s = r.summaries["aslam"]
        n = r.summaries["nearest"]
        if r.drift is None:
            continue
        w(
            f"- **{r.scenario.route}, {r.scenario.laps} laps ({r.keyframes} keyframes).** Defaults: "
            f"precision {fmt(s['loop_closure']['precision'])}, recall {fmt(s['loop_closure']['recall'])}, "
            f"mean delay {fmt(s['relocalisation']['mean_delay_keyframes'], 1)} over "
            f"{s['relocalisation']['episodes']} episode(s), revisit error at most "
            f"{fmt(max(s['error']['best']['x_m']['max'] or 0, s['error']['best']['y_m']['max'] or 0))} m; "
            f"nearest neighbour: precision {fmt(n['loop_closure']['precision'])}, recall "
            f"{fmt(n['loop_closure']['recall'])}; odometry alone drifts to {r.drift.max_m:.2f} m "
            f"({r.drift.max_heading_deg:.0f}°) without loop closure."
        )
    w("")
    if missed:
        w(
            "- **Targets not met:** "
            + "; ".join(f"{a} (goal {b}, measured {c})" for a, b, c, _ in missed)
            + ". See the notes below.\n"
        )
    else:
        w("- **Every speed and memory target is met** in this run.\n")
    notes = []
    for key in ("estimate_laps4", "estimate_laps10"):
        d = speed[key]
        if d["ratio"] > 1.25:
            gap = d["estimate_s"] - d["floor_s"]
            search_share = speed["estimate_laps10"].get("profile", {}).get("_search", float("nan"))
            allowed = 0.25 * d["floor_s"]
            notes.append(
                f"estimate ÷ floor is {d['ratio']:.3f} on {d['keyframes']} keyframes: the estimate takes "
                f"{gap:.3f} s more than the floor, where the target allows {allowed:.3f} s. The SLAM steps "
                f"alone take {d['slam_only_s']:.3f} s ({d['slam_only_s'] / d['keyframes'] * 1e3:.2f} ms per "
                f"keyframe) and the SHA-256 {d['sha256_s']:.3f} s. On this 2-core machine the floor already "
                "keeps both cores busy (the reader and two decoding threads), so the SLAM step, which is "
                "meant to run on the other core, adds its CPU time almost one for one. Closing the gap "
                f"means saving {gap - allowed:.3f} s, e.g. a SLAM step of "
                f"{max(d['slam_only_s'] - (gap - allowed), 0) / d['keyframes'] * 1e3:.2f} ms per keyframe "
                "instead of "
                f"{d['slam_only_s'] / d['keyframes'] * 1e3:.2f} "
                f"(the map search, `HypothesisTree._search`, is {search_share * 100:.0f} % of the step's "
                "time in a profile of this run; `--search-max-states` bounds it), or a third core, where "
                "the step overlaps the decoding as designed."
            )
    for key in ("scaling_blocks", "scaling_random", "scaling_big"):
        d = speed[key]
        if d["ratio_last_over_first"] > 1.3:
            notes.append(
                f"the {d['world']} world ({d['keyframes']:,} keyframes) ends "
                f"{d['ratio_last_over_first']:.2f}× slower per keyframe than it starts "
                "(states searched per keyframe "
                f"{d['searched_states_mean']:.0f}, hypotheses mean {d['hypotheses_mean']:.2f}): "
                + (
                    "the saturated map grows denser in links, so each graph search touches more of it "
                    "within the same uncertainty budget; a bound on links expanded per state, or "
                    "`--search-max-states` lower, could close it (not tried)."
                    if d["world"] == "random"
                    else blocks_note(speed)
                )
            )
    if rec["loop_keyframes_per_second"] < 30:
        notes.append(
            f"recording runs at {rec['loop_keyframes_per_second']:.1f} keyframes/s in this run (the "
            "machine's load decides this absolute figure: Mesa's llvmpipe renders on the same 2 cores); the "
            "ratio to the bare pyrender loop is what the recorder controls."
        )
    if rec["ratio_loop_over_bare"] > 1.3:
        notes.append(
            f"record loop ÷ bare loop {rec['ratio_loop_over_bare']:.2f}: PNG encoding no longer hides behind "
            "rendering; JPEG (`--jpeg-quality`) or a second encoder thread would close it."
        )
    if big.get("fallback"):
        notes.append(
            f"the {big['attempted']:,}-keyframe scaling run exceeded {SCALING_BIG_TIMEOUT_S} s; "
            f"{big['keyframes']:,} keyframes were run instead."
        )
    edge = [a for a, b, c, ok in rows if not ok and _near_target(b, c)]
    if edge:
        notes.append(
            "at the edge: "
            + "; ".join(edge)
            + " missed by less than 5 %. On this shared 2-core machine repeated runs differ by about "
            "that much, so these are borderline rather than clear misses."
        )
    for note in notes:
        w(f"- {note[0].upper()}{note[1:]}")
    if notes:
        w("")


# --- main ------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer seeds, shorter runs (for trying it)")
    parser.add_argument("--doc", type=Path, help="document to write (default docs/benchmarks.md)")
    parser.add_argument("--img", type=Path, help="folder for the plots (default docs/img)")
    args = parser.parse_args()
    quick = args.quick
    doc = args.doc or (
        BENCH / ".cache" / "quick" / "benchmarks.md" if quick else ROOT / "docs" / "benchmarks.md"
    )
    img = args.img or (doc.parent / "img")
    started = datetime.datetime.now().astimezone()
    t0 = time.perf_counter()
    load_start = load_average()
    log("machine ...")
    info = machine()

    seeds = SEEDS[:2] if quick else SEEDS
    paper_scenarios = [Scenario("paper", "paper", 2, s) for s in seeds]
    noise_scenarios = {
        n: ([Scenario("noise", "paper", 2, s, noise=n) for s in seeds] if n != 0.03 else paper_scenarios)
        for n in NOISES
    }
    aliasing_scenarios = [Scenario("aliasing", "paper", 2, s, aliasing=0.5) for s in seeds]
    route_scenarios = [Scenario("routes", "figure8", 3, 1), Scenario("routes", "grid", 3, 1)]
    long_scenarios = [Scenario("long", "grid", 5 if quick else 25, 1)]

    log("tuning the nearest-neighbour threshold on the paper route, seed 1 ...")
    tuning = tuned_threshold(paper_scenarios[0]) | {"seed": paper_scenarios[0].seed}
    threshold = tuning["threshold"]
    log(f"  threshold {threshold:.4f} (F1 {tuning['f1']:.3f})")

    img.mkdir(parents=True, exist_ok=True)
    for old in img.glob("*.png"):
        old.unlink()
    images: dict[str, str] = {}
    runs: dict[str, Run] = {}
    with tempfile.TemporaryDirectory(prefix="aslam-bench-") as folder:
        work = Path(folder)
        ordered = (
            paper_scenarios
            + [s for n in NOISES if n != 0.03 for s in noise_scenarios[n]]
            + aliasing_scenarios
            + route_scenarios
            + long_scenarios
        )
        for i, scenario in enumerate(ordered, 1):
            log(f"[{i}/{len(ordered)}] {scenario.name}")
            plots: dict[str, Path] = {}
            if scenario == paper_scenarios[0]:
                plots["aslam"] = work / "plots-paper"
            if scenario == aliasing_scenarios[0]:
                plots["aslam"] = work / "plots-aliasing"
            runs[scenario.name] = run_scenario(scenario, threshold, work, plots)
        for name, source in (
            ("hypotheses", "plots-paper/hypotheses.png"),
            ("errors", "plots-paper/errors.png"),
            ("map", "plots-paper/map.png"),
            ("aliasing_hypotheses", "plots-aliasing/hypotheses.png"),
        ):
            target = f"{'paper-seed1' if not name.startswith('aliasing') else 'aliasing-seed1'}-" + (
                name.removeprefix("aliasing_") + ".png"
            )
            shutil.copyfile(work / source, img / target)
            images[name] = target
    long_run = runs[long_scenarios[0].name]
    drift_plot(long_run, img / "long-run-drift.png")
    images["drift"] = "long-run-drift.png"

    log("speed benches ...")
    speed = speed_benches(quick)

    families = {
        "paper": [runs[s.name] for s in paper_scenarios],
        "aliasing": [runs[s.name] for s in aliasing_scenarios],
        "routes": [runs[s.name] for s in route_scenarios],
        "long": [runs[s.name] for s in long_scenarios],
    }
    noise_runs = {n: [runs[s.name] for s in noise_scenarios[n]] for n in NOISES}
    total = time.perf_counter() - t0
    doc.parent.mkdir(parents=True, exist_ok=True)
    write_doc(
        doc,
        img,
        started=started,
        total_s=total,
        info=info,
        loads=(load_start, load_average()),
        families=families,
        noise_runs=noise_runs,
        tuning=tuning,
        speed=speed,
        images=images,
        quick=quick,
    )
    dump = {
        name: {
            "scenario": run.scenario.name,
            "keyframes": run.keyframes,
            "summaries": run.summaries,
            "second_lap_accuracy": run.lap2,
            "f1": run.f1,
            "peak_rss_mib": run.peak_rss_mib,
            "wall_s": run.wall_s,
            "drift_final_m": None if run.drift is None else run.drift.final_m,
            "drift_max_m": None if run.drift is None else run.drift.max_m,
        }
        for name, run in runs.items()
    }
    raw = BENCH / ".cache" / ("last-run-quick.json" if quick else "last-run.json")
    raw.write_text(json.dumps({"runs": dump, "speed": speed, "tuning": tuning, "machine": info}, indent=1))
    log(f"wrote {doc} and {len(list(img.glob('*.png')))} plots in {img} ({total:.0f} s)")


if __name__ == "__main__":
    main()
