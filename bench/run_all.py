"""`make bench`: every benchmark in one run, its raw results in one JSON file, then the document.

    python bench/run_all.py [--quick] [--results bench/results/benchmarks.json] [--no-render]

1. Scenarios recorded with ``aslam record`` (cached in bench/.cache/), each run through
   ``aslam estimate`` (project defaults and ``--paper-faithful``) and ``aslam report --json -``,
   and through the baselines of ``bench/baselines.py`` (odometry only, nearest neighbour), all
   scored by ``aslam.core.metrics.evaluate``.
2. Speed and scaling (``bench/speed.py``): the speed benches in subprocesses (``--json``), ratios
   measured within one run.
3. The raw results to ``bench/results/benchmarks.json`` (sorted keys, so a re-run diffs cleanly), the
   report's plots of two runs to ``docs/img/``; then ``bench/render.py`` writes ``docs/benchmarks.md``
   and the bench's own plot from that file alone (``make bench-doc`` repeats just that step).

``--quick`` (two seeds, shorter runs, no 100,000-keyframe run) is for trying the script; it
writes to bench/.cache/quick/ unless --results/--doc/--img are given.

The results: ``machine`` (ordered rows), ``tuning`` (the nearest neighbour's threshold), ``families``
(run names per scenario family; ``noise`` one list per σ in ``noises``), ``runs`` (per run: the
scenario, ``methods`` with each method's ``aslam report`` summary plus the bench's scores, the
odometry ``drift``, and per-keyframe ``series`` for the runs the document plots or narrates) and
``speed`` (each speed bench's own ``--json`` output).
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from measure import log

sys.path.insert(0, str(Path(__file__).resolve().parent))

import baselines
import render
import scenarios
import speed
from dask_tasks import as_tasks
from machine import load_average, machine
from scenarios import ROOT, Scenario

from aslam.app.score import build_summary
from aslam.core.config import EstimatorConfig
from aslam.core.metrics import Evaluation, evaluate

RESULTS = ROOT / "bench" / "results" / "benchmarks.json"
QUICK = ROOT / "bench" / ".cache" / "quick"
SEEDS = (1, 2, 3, 4, 5)
NOISES = (0.01, 0.03, 0.05, 0.10)
REPORT_PLOTS = {"paper-seed1": ("hypotheses", "errors", "map"), "aliasing-seed1": ("hypotheses",)}
"""``aslam report --plots`` figures of the first paper and aliasing runs kept for the document."""

# --- one scenario ----------------------------------------------------------------------------------


def method_scores(evaluation: Evaluation, summary: dict[str, Any], scenario: Scenario) -> dict[str, Any]:
    """One method on one recording: the summary JSON and the counts the document adds to it."""
    start = scenario.second_lap_from
    lap2 = None
    if start is not None and evaluation.keyframes > start:
        lap2 = float(evaluation.correct[start:].mean())
    wrong = evaluation.wrong
    return {
        "summary": summary,
        "f1": baselines.f1(evaluation),
        "second_lap_accuracy": lap2,
        "wrong_claims": int(wrong.sum()),
        "missed_revisits": int((evaluation.true_revisit & ~evaluation.correct).sum()),
        "worst_claim_m": float(
            np.nanmax(np.hypot(evaluation.best_error[:, 0], evaluation.best_error[:, 1]), initial=0.0)
        ),
    }


def series(values: np.ndarray) -> list[float | None]:
    """A per-keyframe series for the JSON, NaN as null; full precision, so the plot drawn from the
    JSON is the plot drawn from the measurement, byte for byte."""
    return [None if not np.isfinite(v) else float(v) for v in values]


def run_scenario(scenario: Scenario, threshold: float, work: Path, plots: Path | None, detail: bool) -> dict:
    """Record (or take from the cache), estimate with both settings, report, and run the baselines.

    ``plots``: where ``aslam report --plots`` draws the defaults' figures; ``detail``: keep the
    per-keyframe series (hypothesis counts, odometry drift, best-hypothesis error) in the results.
    """
    path, record_s = scenarios.recording(scenario, log=log)
    keyframes = baselines.read_keyframes(path)
    n = len(keyframes.stamps_ns)
    methods: dict[str, dict[str, Any]] = {}
    evaluations: dict[str, Evaluation] = {}
    mismatch = []
    for method in scenarios.ESTIMATORS:
        estimate = work / f"{scenario.short_name}-{method}.mcap"
        result = scenarios.estimate_and_report(
            path, estimate, scenario, method, plots=plots if method == "aslam" else None
        )
        summary = result["summary"]
        steps = scenarios.estimate_steps(estimate)
        estimate.unlink()
        evaluation = evaluations[method] = evaluate(steps, keyframes.true_poses)
        methods[method] = method_scores(evaluation, summary, scenario)
        methods[method] |= {"peak_rss_mib": result["peak_rss_mib"], "wall_s": result["wall_s"]}
        # The report and this bench must agree (same keyframes, same ground truth, same scoring).
        if len(steps) != n or summary["loop_closure"]["precision"] != evaluation.precision:
            mismatch.append(
                {
                    "method": method,
                    "report_keyframes": summary["keyframes"],
                    "report_precision": summary["loop_closure"]["precision"],
                    "bench_keyframes": n,
                    "bench_precision": evaluation.precision,
                }
            )
    matches = baselines.nearest_neighbours(keyframes.histograms)
    nearest = baselines.nearest_neighbour(keyframes, threshold, matches)
    t = np.flatnonzero(nearest.wrong)
    odometry = baselines.odometry_only(keyframes)
    for method, evaluation in (("nearest", nearest), ("odometry", odometry)):
        states = int((~evaluation.claims).sum())
        summary = build_summary(evaluation, states=states, links=0, keyframes_per_second=None)
        methods[method] = method_scores(evaluation, summary, scenario)
    drift = baselines.odometry_drift(keyframes)
    run = {
        "scenario": {
            "name": scenario.name,
            "short_name": scenario.short_name,
            "command": scenario.command(),
            "route": scenario.route,
            "laps": scenario.laps,
            "seed": scenario.seed,
            "noise": scenario.noise,
            "aliasing": scenario.aliasing,
            "second_lap_from": scenario.second_lap_from,
        },
        "keyframes": n,
        "true_revisits": int(odometry.true_revisit.sum()),
        "record_s": record_s,
        "methods": methods,
        "drift": {
            "final_m": drift.final_m,
            "max_m": drift.max_m,
            "max_heading_deg": drift.max_heading_deg,
            "error": drift.axis_stats(),
        },
        "nearest_wrong_recent": int((t - matches[0][t] <= 3).sum()),
        "mismatch": mismatch,
    }
    if detail:
        kept = evaluations["aslam"]
        run["series"] = {
            "hypotheses": kept.hypothesis_counts.astype(int).tolist(),
            "odometry_error_m": series(drift.position_m),
            "best_error_m": series(np.hypot(kept.best_error[:, 0], kept.best_error[:, 1])),
        }
    return run


def run_on_dask(
    jobs: dict[Scenario, tuple[Path | None, bool]], threshold: float, work: Path
) -> Iterator[tuple[Scenario, dict[str, Any]]]:
    """Every scenario as a task on the sweep's local Dask cluster (``bench/dask_tasks.py``); results
    as they finish.

    Each task records (cached), runs ``aslam estimate``/``aslam report`` as processes (their wall
    time and peak memory are per process, taken while another scenario may run on the other core)
    and the baselines. The figures do not depend on the order; ``runs`` is keyed by name.
    """
    order = list(jobs)
    calls = [(scenario, threshold, work, *jobs[scenario]) for scenario in order]
    for i, run in as_tasks(run_scenario, calls):
        yield order[i], run


def tuned_threshold(scenario: Scenario) -> dict[str, Any]:
    """The nearest neighbour's χ² threshold, tuned for F1 on ``scenario`` and used unchanged elsewhere."""
    path, _ = scenarios.recording(scenario, log=log)
    threshold, evaluation = baselines.tune_threshold(baselines.read_keyframes(path))
    return {
        "threshold": threshold,
        "precision": evaluation.precision,
        "recall": evaluation.recall,
        "f1": baselines.f1(evaluation),
        "seed": scenario.seed,
    }


# --- the whole run ---------------------------------------------------------------------------------


def families(quick: bool) -> dict[str, Any]:
    """The scenarios of one run by family; the noise sweep shares its σ = 0.03 runs with the paper route."""
    seeds = SEEDS[:2] if quick else SEEDS
    paper = [Scenario("paper", "paper", 2, s) for s in seeds]
    noise = [
        [Scenario("noise", "paper", 2, s, noise=n) for s in seeds] if n != 0.03 else paper for n in NOISES
    ]
    return {
        "paper": paper,
        "noise": noise,
        "aliasing": [Scenario("aliasing", "paper", 2, s, aliasing=0.5) for s in seeds],
        "routes": [Scenario("routes", "figure8", 3, 1), Scenario("routes", "grid", 3, 1)],
        "long": [Scenario("long", "grid", 5 if quick else 25, 1)],
    }


def measure(quick: bool, img: Path) -> dict[str, Any]:
    """Run every scenario and speed bench; the raw results (and the report's plots in ``img``)."""
    started = datetime.datetime.now().astimezone()
    t0 = time.perf_counter()
    load_start = load_average()
    log("machine ...")
    info = machine(ROOT)
    family = families(quick)
    paper, aliasing, long_run = family["paper"][0], family["aliasing"][0], family["long"][0]

    log("tuning the nearest-neighbour threshold on the paper route, seed 1 ...")
    tuning = tuned_threshold(paper)
    log(f"  threshold {tuning['threshold']:.4f} (F1 {tuning['f1']:.3f})")

    img.mkdir(parents=True, exist_ok=True)
    for old in img.glob("*.png"):
        old.unlink()
    plotted = {paper: "paper-seed1", aliasing: "aliasing-seed1"}
    images: list[str] = []
    runs: dict[str, dict[str, Any]] = {}
    groups = [group for name, scenes in family.items() for group in (scenes if name == "noise" else [scenes])]
    ordered = list(dict.fromkeys(s for group in groups for s in group))
    with tempfile.TemporaryDirectory(prefix="aslam-bench-") as folder:
        work = Path(folder)
        jobs = {
            scenario: (
                work / f"plots-{plotted[scenario]}" if scenario in plotted else None,
                scenario in (paper, long_run),
            )
            for scenario in ordered
        }
        for done, (scenario, run) in enumerate(run_on_dask(jobs, tuning["threshold"], work), 1):
            log(f"[{done}/{len(ordered)}] {scenario.name}")
            runs[scenario.name] = run
        for scenario, (plots, _detail) in jobs.items():
            for kind in REPORT_PLOTS[plotted[scenario]] if plots else ():
                images.append(f"{plotted[scenario]}-{kind}.png")
                shutil.copyfile(plots / f"{kind}.png", img / images[-1])

    log("speed benches ...")
    speed_results = speed.speed_benches(quick)
    return {
        "quick": quick,
        "started": started.isoformat(timespec="seconds"),
        "total_s": time.perf_counter() - t0,
        "load_average": {"start": load_start, "end": load_average()},
        "machine": info,
        "estimator_defaults": {"search_max_states": EstimatorConfig().search_max_states},
        "tuning": tuning,
        "families": {
            name: [[s.name for s in group] for group in scenes]
            if name == "noise"
            else [s.name for s in scenes]
            for name, scenes in family.items()
        },
        "noises": list(NOISES),
        "images": images,
        "runs": runs,
        "speed": speed_results,
    }


def write_results(results: dict[str, Any], path: Path) -> None:
    """Sorted keys and lists of plain numbers on one line: a re-run diffs line by line."""
    text = json.dumps(results, indent=1, sort_keys=True, ensure_ascii=False, allow_nan=False)
    text = re.sub(r"\[[^\[\]{}\"]*\]", lambda m: json.dumps(json.loads(m[0])), text)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer seeds, shorter runs (for trying it)")
    parser.add_argument("--results", type=Path, help=f"results JSON to write (default {RESULTS})")
    parser.add_argument("--doc", type=Path, help="document to write (default docs/benchmarks.md)")
    parser.add_argument("--img", type=Path, help="folder for the plots (default docs/img)")
    parser.add_argument("--no-render", action="store_true", help="measure only; render later with render.py")
    args = parser.parse_args()
    results_path = args.results or (QUICK / "benchmarks.json" if args.quick else RESULTS)
    doc = args.doc or (QUICK / "benchmarks.md" if args.quick else ROOT / "docs" / "benchmarks.md")
    img = args.img or (doc.parent / "img")
    results = measure(args.quick, img)
    write_results(results, results_path)
    log(f"wrote {results_path} ({results['total_s']:.0f} s)")
    if not args.no_render:
        render.render(results_path, doc, img)
        log(f"wrote {doc} and {len(list(img.glob('*.png')))} plots in {img}")


if __name__ == "__main__":
    main()
