"""`make bench-doc`: docs/benchmarks.md and the bench's plot from the results JSON alone, in seconds.

    python bench/render.py [--results bench/results/benchmarks.json] [--doc docs/benchmarks.md] [--img DIR]

The words are in ``bench/templates/benchmarks.md`` (Jinja2: the document's sentences depend on the
figures, e.g. which targets were missed, and a template without conditions would push those
sentences back into Python); this module computes the values and table rows it shows.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import tables
from tables import Run, agg, fmt, mean, scores, summaries

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results" / "benchmarks.json"
ROBUST_TABLES = {
    "robust_matrix": "robust_matrix.md",
    "robust_held_out": "robust_matrix_held_out.md",
    "robust_mixes": "robust_matrix_mixes.md",
    "robust_later": "robust_matrix_seeds_9_10.md",
    "robust_latest": "robust_matrix_seeds_11_12.md",
    "robust_fresh": "robust_matrix_seeds_13_14.md",
    "robust_fresh_mixes": "robust_matrix_mixes_seeds_13_14.md",
    "robust_events_15_16": "robust_matrix_seeds_15_16.md",
    "robust_held_out_19_20": "robust_matrix_seeds_19_20.md",
    "robust_route_shapes": "robust_matrix_route_shapes.md",
    "robust_route_curves": "robust_matrix_route_curves.md",
    "robust_seeds_23_24": "robust_matrix_seeds_23_24.md",
    "robust_sparse_events": "robust_matrix_sparse_events.md",
    "robust_seeds_27_28": "robust_matrix_seeds_27_28.md",
    "robust_seeds_29_30": "robust_matrix_seeds_29_30.md",
    "robust_seeds_31_32": "robust_matrix_seeds_31_32.md",
    "robust_seeds_33_34": "robust_matrix_seeds_33_34.md",
    "robust_seeds_35_36": "robust_matrix_seeds_35_36.md",
    "robust_seeds_41_42": "robust_matrix_seeds_41_42.md",
    "robust_seeds_43_44": "robust_matrix_seeds_43_44.md",
    "robust_seeds_45_46": "robust_matrix_seeds_45_46.md",
    "robust_figure8_47_66": "robust_matrix_figure8_seeds_47_66.md",
    "robust_seeds_67_68": "robust_matrix_seeds_67_68.md",
    "robust_seeds_69_70": "robust_matrix_seeds_69_70.md",
    "robust_stops": "robust_matrix_stops.md",
    "robust_seeds_71_72": "robust_matrix_seeds_71_72.md",
    "robust_seeds_73_74": "robust_matrix_seeds_73_74.md",
    "robust_seeds_75_76": "robust_matrix_seeds_75_76.md",
    "robust_seeds_79_81": "robust_matrix_seeds_79_81.md",
    "robust_seeds_84_85": "robust_matrix_seeds_84_85.md",
    "robust_seeds_86_87": "robust_matrix_seeds_86_87.md",
    "robust_seeds_88_89": "robust_matrix_seeds_88_89.md",
    "robust_seeds_90_91": "robust_matrix_seeds_90_91.md",
    "robust_phases_88_91": "robust_matrix_seeds_88_91_phases.md",
    "robust_seeds_92_93": "robust_matrix_seeds_92_93.md",
    "robust_seeds_94_95": "robust_matrix_seeds_94_95.md",
    "robust_seeds_96_97": "robust_matrix_seeds_96_97.md",
    "robust_seeds_98_99": "robust_matrix_seeds_98_99.md",
    "recorder_events": "recorder_events.md",
    "recorder_events_lighting50": "recorder_events_lighting50.md",
    "recorder_events_fps5": "recorder_events_fps5.md",
    "recorder_events_98_99": "recorder_events_seeds_98_99.md",
    "recorder_events_98_99_lighting50": "recorder_events_seeds_98_99_lighting50.md",
    "recorder_events_98_99_fps5": "recorder_events_seeds_98_99_fps5.md",
    "robust_seeds_100_101": "robust_matrix_seeds_100_101.md",
    "robust_events_100_101": "robust_matrix_events_100_101.md",
    "recorder_events_100_101": "recorder_events_seeds_100_101.md",
    "recorder_events_100_101_lighting50": "recorder_events_seeds_100_101_lighting50.md",
    "recorder_events_100_101_fps5": "recorder_events_seeds_100_101_fps5.md",
    "robust_seeds_104_105": "robust_matrix_seeds_104_105.md",
    "robust_events_104_105": "robust_matrix_events_104_105.md",
    "recorder_events_104_105": "recorder_events_seeds_104_105.md",
    "recorder_events_104_105_lighting50": "recorder_events_seeds_104_105_lighting50.md",
    "recorder_events_104_105_fps5": "recorder_events_seeds_104_105_fps5.md",
    "robust_seeds_108_109": "robust_matrix_seeds_108_109.md",
    "robust_seeds_110_111": "robust_matrix_seeds_110_111.md",
    "robust_seeds_114_115": "robust_matrix_seeds_114_115.md",
    "robust_seeds_116_117": "robust_matrix_seeds_116_117.md",
    "robust_seeds_120_121": "robust_matrix_seeds_120_121.md",
    "robust_seeds_122_123": "robust_matrix_seeds_122_123.md",
    "robust_seeds_124_125": "robust_matrix_seeds_124_125.md",
    "robust_seeds_126_127": "robust_matrix_seeds_126_127.md",
    "robust_seeds_128_129": "robust_matrix_seeds_128_129.md",
    "robust_seeds_130_131": "robust_matrix_seeds_130_131.md",
    "robust_seeds_132_133": "robust_matrix_seeds_132_133.md",
    "robust_seeds_134_135_sparse": "robust_matrix_seeds_134_135_sparse.md",
    "robust_seeds_136_137": "robust_matrix_seeds_136_137.md",
    "robust_seeds_138_139": "robust_matrix_seeds_138_139.md",
    "robust_random_mixes_500": "robust_matrix_random_mixes_500.md",
    "robust_random_mixes_500_events": "robust_matrix_random_mixes_500_events.md",
    "robust_random_mixes_501": "robust_matrix_random_mixes_501.md",
    "robust_random_mixes_502": "robust_matrix_random_mixes_502.md",
    "robust_random_mixes_503": "robust_matrix_random_mixes_503.md",
    "robust_random_mixes_504": "robust_matrix_random_mixes_504.md",
    "robust_random_mixes_505": "robust_matrix_random_mixes_505.md",
    "robust_random_mixes_506": "robust_matrix_random_mixes_506.md",
    "robust_random_mixes_507": "robust_matrix_random_mixes_507.md",
    "robust_random_mixes_508": "robust_matrix_random_mixes_508.md",
    "robust_random_mixes_509": "robust_matrix_random_mixes_509.md",
    "robust_reset_shares": "robust_matrix_reset_shares.md",
    "robust_resets_102_103": "robust_matrix_resets_102_103.md",
    "robust_kidnap_windows_96_99": "robust_matrix_kidnap_windows_96_99.md",
    "robust_exceptions_rechecked": "robust_matrix_exceptions_rechecked.md",
    "robust_geometric_check": "robust_matrix_geometric_check.md",
    "robust_seeds_82_83": "robust_matrix_seeds_82_83.md",
    "robust_seeds_82_83_geometric_check": "robust_matrix_seeds_82_83_geometric_check.md",
    "robust_recorder_settings": "robust_matrix_recorder_settings.md",
}
"""The robust-revisit matrix's tables (``bench/robust_matrix.py --markdown``), beside the results,
by the template's name for each: the matrix; the same families on held-out seeds and routes (seeds
6–8); mixes of its knobs, held out; seeds 9–10; seeds 11–12 with a sixth route
(``bench/routes/notch.json``); seeds 13–14 with jitter and wander too, and the mixes on them; the
events and aliasing on seeds 15–16; the events, the families with targets and six mixes on seeds 19–20,
held out; the route files with other turns and steps; those with arcs, zigzags and 0.75 m steps; seeds
23–24 on eight routes with three-knob mixes and events on dense and noisy streams; kidnaps and resets on
sparse streams; seeds 27–28, rendered after that day's changes; seeds 29–30 on video-rate streams,
rendered after the window's sharper motion term; seeds 31–32 on seven routes, the families with
targets, rendered a session later with the estimator unchanged (and seeds 33–34 and 35–36, each a
session later again, 35–36 with two more mixes; 41–42 and 43–44 on nine routes each; 45–46 after
the look-alike rule, with kidnaps at three points of the run, the figure-8 at aliasing 1.0 and its
kidnaps on seeds 47–66; seeds 67–68 after both; 69–70 after a pause counted as a possible carry;
71–72 with stops; 73–74 after its final form; 75–76 after the turn-in-place rule; 79–81 on two route
shapes made after it); stops derived from the matrix's renders; the matrix with the geometric check
on; recorder settings the families never vary (image size, JPEG, lens, laps, camera height). A table
not made is left out of the page."""
TEMPLATES = Path(__file__).resolve().parent / "templates"
DRIFT_PLOT = "long-run-drift.png"


def family(runs: list[Run], label: str | None = None) -> dict[str, Any]:
    """What the document shows of a group of runs (five seeds of a scenario, or one route)."""
    methods = tables.METHODS
    f1 = {m: mean(scores(runs, m, "f1")) or 0.0 for m in methods}
    return {
        "runs": runs,
        "first": runs[0],
        "seeds": ", ".join(str(r["scenario"]["seed"]) for r in runs),
        "lap2": tables.has_second_lap(runs),
        "true_revisits": agg([r["true_revisits"] for r in runs], 0),
        "drift": {
            key: agg(tables.drift_values(runs, key), 1 if "heading" in key else 2)
            for key in runs[0]["drift"]
            if key != "error"
        },
        "loop": tables.loop_closing_rows(runs, label),
        "errors": tables.error_rows(runs, label),
        "cost": tables.cost_rows(runs, label),
        "f1": f1,
        "lap2_mean": mean(scores(runs, "aslam", "second_lap_accuracy")),
        "precision": {m: mean(summaries(runs, m, "loop_closure.precision")) for m in methods},
        "recall": {m: mean(summaries(runs, m, "loop_closure.recall")) for m in methods},
        "winner": tables.METHOD_NAMES[max(("aslam", "paper-faithful", "nearest"), key=lambda m: f1[m])],
        "first_delay": {
            m: agg(summaries(runs, m, "relocalisation.first_delay_keyframes"), 1, "never") for m in methods
        },
        "wrong": {m: sum(scores(runs, m, "wrong_claims")) for m in methods},
        "missed": {m: sum(scores(runs, m, "missed_revisits")) for m in methods},
        "hypotheses_max": summaries(runs, "aslam", "hypotheses.max"),
        "drift_max_mean": float(np.mean(tables.drift_values(runs, "max_m"))),
        "f1_margin": f1["aslam"] - f1["nearest"],
    }


def comparison(seed1: Run, paper: list[Run]) -> dict[str, Any]:
    """The paper's figures 8–11 set against seed 1 with the project defaults."""
    s1 = seed1["methods"]["aslam"]["summary"]
    lap = seed1["scenario"]["second_lap_from"]
    counts = np.asarray(seed1["series"]["hypotheses"])
    several = counts > 1
    best = s1["error"]["best"]
    firsts = summaries(paper, "aslam", "relocalisation.first_delay_keyframes")
    firsts += summaries(paper, "paper-faithful", "relocalisation.first_delay_keyframes")
    return {
        "first_lap_max": int(counts[:lap].max(initial=1)),
        "spans": tables.spans(several),
        "back_to_one": int(np.flatnonzero(several)[-1]) + 1 if several.any() and counts[-1] == 1 else None,
        "final": int(counts[-1]),
        "within_jitter": best["x_m"]["max"] is not None
        and max(best["x_m"]["max"], best["y_m"]["max"]) <= 0.25,
        "sooner": all(d is not None and d < 14 for d in firsts),
    }


def notes(speed: dict[str, Any], search_max_states: int) -> dict[str, Any]:
    """The figures behind the notes on missed speed targets."""
    estimate = []
    profile = speed[tables.ESTIMATES[0][0]].get("profile", {})
    for key, label in tables.ESTIMATES:
        d = speed[key]
        if d["ratio_of_medians"] > 1.0:
            stages = d["stages"]
            estimate.append(
                d
                | {
                    "label": label,
                    "gap": d["estimate_s"]["median"] - d["floor_s"]["median"],
                    "step_ms": stages["slam_s"] / stages["keyframes"] * 1e3,
                    "search_pct": profile.get("_search", float("nan")) * 100,
                }
            )
    small, big = speed["scaling_blocks"], speed["scaling_big"]
    rows = tables.target_rows(speed)
    short, long = speed["estimate_320x240"], speed["estimate_320x240_long"]
    more = (long["stages"]["keyframes"] - short["stages"]["keyframes"]) / 1e3
    return {
        "estimate": estimate,
        # What each keyframe past the fixed costs costs, from the grid route's 2 laps to its 8 (ms).
        "estimate_per_keyframe_ms": (long["estimate_s"]["median"] - short["estimate_s"]["median"]) / more,
        "floor_per_keyframe_ms": (long["floor_s"]["median"] - short["floor_s"]["median"]) / more,
        "scaling": [
            speed[k]
            for k in ("scaling_blocks", "scaling_random", "scaling_big")
            if speed[k]["ratio_last_over_first"] > 1.3
        ],
        "blocks": {
            "small": small,
            "big": big,
            "growth": big["last_ms"] / small["last_ms"],
            "cap": search_max_states,
        },
        "targets": rows,
        "missed": [r for r in rows if not r[3]],
        "edge": [name for name, goal, measured, ok in rows if not ok and tables.near_target(goal, measured)],
    }


def context(
    results: dict[str, Any], rel_img: str, robust_tables: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """Every value the template shows, from the results JSON (and the robust-revisit matrix's
    tables, made apart by ``bench/robust_matrix.py``, when there are: see ``ROBUST_TABLES``)."""
    runs = results["runs"]
    by_name = {
        name: [runs[n] for n in names] for name, names in results["families"].items() if name != "noise"
    }
    noise = [
        (sigma, [runs[n] for n in names])
        for sigma, names in zip(results["noises"], results["families"]["noise"], strict=True)
    ]
    paper, aliasing = by_name["paper"], by_name["aliasing"]
    seed1 = paper[0]["scenario"]
    minutes, seconds = divmod(round(results["total_s"]), 60)
    every = paper + aliasing + by_name["routes"] + by_name["long"]
    routes = [(r, family([r], r["scenario"]["route"])) for r in by_name["routes"]]
    later = [(r, family([r])) for r in by_name["routes"] + by_name["long"]]
    shown = {name: family(by_name[name]) for name in ("paper", "aliasing", "long")}
    margins = [("paper route", shown["paper"]["f1_margin"]), ("aliasing", shown["aliasing"]["f1_margin"])]
    margins += [(f"{r['scenario']['route']} ×{r['scenario']['laps']}", f["f1_margin"]) for r, f in later]
    return shown | {
        "results": results,
        **{name: (robust_tables or {}).get(name) for name in ROBUST_TABLES},
        "started": f"{datetime.datetime.fromisoformat(results['started']):%Y-%m-%d %H:%M %Z}",
        "minutes": minutes,
        "seconds": seconds,
        "img": rel_img,
        "images": results["images"] + [DRIFT_PLOT],
        "speed": results["speed"],
        "tuning": results["tuning"],
        "lap": seed1["second_lap_from"],
        "commands": {
            "paper": seed1["command"].replace(f"--seed {seed1['seed']}", "--seed S"),
            "noise": noise[0][1][0]["scenario"]["command"]
            .replace(f"--seed {noise[0][1][0]['scenario']['seed']}", "--seed S")
            .replace(f"--noise {noise[0][0]:g}", "--noise σ"),
            "aliasing": aliasing[0]["scenario"]["command"].replace(
                f"--seed {aliasing[0]['scenario']['seed']}", "--seed S"
            ),
        },
        "noises": ", ".join(f"{n:g}" for n in results["noises"]),
        "routes": routes,
        "route_rows": {key: [row for _, f in routes for row in f[key]] for key in ("loop", "errors", "cost")}
        | {"lap2": tables.has_second_lap(by_name["routes"])},
        "later": later,
        "earns": [(name, margin) for name, margin in margins if margin >= 0.02],
        "level": [(name, margin) for name, margin in margins if margin < 0.02],
        "noise": [(sigma, family(group)) for sigma, group in noise],
        "noise_rows": {"loop": tables.noise_rows(noise), "lap2": tables.has_second_lap(noise[0][1])},
        "per_seed": tables.per_seed_rows(paper),
        "mismatches": [(r["scenario"]["name"], m) for r in every for m in r["mismatch"]],
        "comparison": comparison(paper[0], paper),
        "nearest_recent": sum(r["nearest_wrong_recent"] for r in paper),
        "nearest_far": max(r["methods"]["nearest"]["worst_claim_m"] for r in aliasing),
        "all_max": max(summaries(every, "aslam", "hypotheses.max")),
        "all_mean": max(summaries(every, "aslam", "hypotheses.mean")),
        "pf_max": max(summaries(every, "paper-faithful", "hypotheses.max")),
        "estimate_rows": tables.estimate_rows(results["speed"]),
        "stage_rows": tables.stage_rows(results["speed"]),
        "scaling_rows": tables.scaling_rows(results["speed"]),
        "notes": notes(results["speed"], results["estimator_defaults"]["search_max_states"]),
    }


def drift_plot(run: Run, path: Path) -> None:
    """Odometry drift against the estimator's best-hypothesis error, per keyframe (long run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = run["series"]
    odometry = np.array(series["odometry_error_m"], dtype=float)
    best = np.array([np.nan if v is None else v for v in series["best_error_m"]], dtype=float)
    t = np.arange(run["keyframes"])
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.plot(t, odometry, color="tab:red", lw=1.2, label="odometry only: |odometry − truth|")
    ax.plot(t, best, ".", ms=2, color="tab:blue", label="aslam best hypothesis: revisit position error")
    ax.set_xlabel("keyframe")
    ax.set_ylabel("position error (m)")
    ax.set_ylim(bottom=0)
    ax.set_title(f"{run['scenario']['short_name']}: what the error grows to without loop closure")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def render_text(
    results: dict[str, Any], rel_img: str = "img", robust_tables: Mapping[str, str] | None = None
) -> str:
    """The document for ``results`` (no file written)."""
    import jinja2

    environment = jinja2.Environment(
        loader=jinja2.FileSystemLoader(TEMPLATES),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    environment.filters |= {"fmt": fmt, "agg": agg, "f": format}
    environment.globals["table"] = tables.table
    text = environment.get_template("benchmarks.md").render(context(results, rel_img, robust_tables))
    return text.rstrip() + "\n"


def render(results_path: Path, doc: Path, img: Path) -> None:
    """Write ``doc`` and the bench's plot in ``img`` from the results JSON at ``results_path``."""
    results = json.loads(results_path.read_text())
    img.mkdir(parents=True, exist_ok=True)
    long_run = results["runs"][results["families"]["long"][0]]
    drift_plot(long_run, img / DRIFT_PLOT)
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(render_text(results, os.path.relpath(img, doc.parent), robust_tables(results_path)))


def robust_tables(results_path: Path) -> dict[str, str]:
    """The robust-revisit matrix's tables beside the results JSON, by the template's name for each."""
    paths = {name: results_path.with_name(file) for name, file in ROBUST_TABLES.items()}
    return {name: path.read_text() for name, path in paths.items() if path.exists()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=RESULTS, help="results JSON of `make bench`")
    parser.add_argument("--doc", type=Path, default=ROOT / "docs" / "benchmarks.md", help="document to write")
    parser.add_argument("--img", type=Path, help="folder for the plots (default: img/ beside the document)")
    args = parser.parse_args()
    render(args.results, args.doc, args.img or args.doc.parent / "img")
    print(f"wrote {args.doc}", file=sys.stderr)


if __name__ == "__main__":
    main()
