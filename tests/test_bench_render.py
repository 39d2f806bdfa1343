"""bench/render.py: the benchmark document from a tiny hand-made results JSON (no measuring)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench"
sys.path.insert(0, str(BENCH))

import render  # noqa: E402


def stats(mean: float | None, high: float | None) -> dict[str, dict[str, float | None]]:
    return {axis: {"mean": mean, "max": high} for axis in ("x_m", "y_m", "heading_deg")}


def method(precision: float | None, recall: float, f1: float, wrong: int, hypotheses_max: int = 1) -> dict:
    claims = 0 if precision is None else 10
    return {
        "summary": {
            "keyframes": 69,
            "states": 35,
            "links": 40,
            "ground_truth": True,
            "hypotheses": {"max": hypotheses_max, "mean": 1.25, "final": 1},
            "relocalisation": {
                "episodes": 0 if precision is None else 1,
                "first_delay_keyframes": None if precision is None else 3,
                "mean_delay_keyframes": None if precision is None else 3.0,
            },
            "loop_closure": {
                "claims": claims,
                "correct": claims - wrong,
                "ground_truth_revisits": 35,
                "precision": precision,
                "recall": recall,
            },
            "error": {"best": stats(0.05, 0.125), "weighted": stats(0.0625, 0.25)},
            "timing": {"keyframes_per_second": 250.0},
        },
        "f1": f1,
        "second_lap_accuracy": recall,
        "wrong_claims": wrong,
        "missed_revisits": 35 - round(recall * 35),
        "worst_claim_m": 0.5,
        "peak_rss_mib": 80.0,
        "wall_s": 0.5,
    }


def run(name: str, route: str, seed: int) -> dict[str, Any]:
    return {
        "scenario": {
            "name": name,
            "short_name": f"{route}-seed{seed}",
            "command": f"aslam record --route {route} --laps 2 --seed {seed} --noise 0.03 -o REC.mcap",
            "route": route,
            "laps": 2,
            "seed": seed,
            "noise": 0.03,
            "aliasing": 0.0,
            "second_lap_from": 34 if route == "paper" else None,
        },
        "keyframes": 69,
        "true_revisits": 35,
        "record_s": None,
        "methods": {
            "aslam": method(0.75, 0.5, 0.6, 4, hypotheses_max=2),
            "paper-faithful": method(0.5, 0.25, 1 / 3, 7),
            "nearest": method(0.875, 0.625, 0.7291, 1),
            "odometry": method(None, 0.0, 0.0, 0),
        },
        "drift": {"final_m": 0.5, "max_m": 1.5, "max_heading_deg": 9.0, "error": stats(0.25, 0.75)},
        "nearest_wrong_recent": 1,
        "mismatch": [],
        "series": {
            "hypotheses": [1] * 40 + [2] * 3 + [1] * 26,
            "odometry_error_m": [i / 100 for i in range(69)],
            "best_error_m": [None] * 34 + [0.05] * 35,
        },
    }


def speed() -> dict[str, Any]:
    estimate = {
        "command": "python bench/estimate_bench.py --route grid --size 320x240 --repeats 3",
        "recording": "REC.mcap",
        "size_mb": 33.7,
        "floor_s": {"median": 0.2, "min": 0.19, "max": 0.22},
        "estimate_s": {"median": 0.3, "min": 0.28, "max": 0.33},
        "ratio_of_medians": 1.5,
        "pair_ratio": {"median": 1.5, "min": 1.4, "max": 1.6},
        "help_s": {"median": 0.21, "min": 0.2, "max": 0.25},
        "estimate_startup_s": {"median": 0.45, "min": 0.4, "max": 0.5},
        "help_samples_s": [0.2, 0.21, 0.25],
        "estimate_startup_samples_s": [0.4, 0.45, 0.45],
        "floor_libraries_s": {"median": 0.18, "min": 0.17, "max": 0.2},
        "estimate_libraries_s": {"median": 0.42, "min": 0.4, "max": 0.45},
        "keyframes_per_second": 466.0,
        "stages": {
            "read_and_sync_s": 0.01,
            "decode_s": 0.05,
            "describe_s": 0.08,
            "slam_s": 0.045,
            "metric_view_imports_s": 0.13,
            "metric_view_s": 0.02,
            "write_s": 0.002,
            "sha256_s": 0.021,
            "keyframes": 145,
        },
        "profile": {"_search": 0.61},
    }
    scaling = {
        "command": "python bench/slam_scaling_bench.py --keyframes 10000 --world blocks",
        "world": "blocks",
        "keyframes": 10000,
        "states": 4081,
        "first_ms": 0.7,
        "first_ms_at_start": 0.68,
        "last_ms": 0.8,
        "ratio_last_over_first": 1.143,
        "ratio_at_start": 1.176,
        "second_ms": 0.75,
        "ratio_last_over_second": 1.067,
        "hypotheses_mean": 1.0,
        "hypotheses_max": 1,
        "searched_states_mean": 195.0,
        "peak_rss_mib": 119.0,
        "bench_wall_s": 9.0,
    }
    return {
        "estimate_320x240": estimate,
        "estimate_320x240_long": estimate
        | {
            "ratio_of_medians": 0.95,
            "floor_s": {"median": 0.8, "min": 0.79, "max": 0.82},
            "estimate_s": {"median": 0.76, "min": 0.75, "max": 0.78},
            "stages": estimate["stages"] | {"keyframes": 580},
        },
        "estimate_640x480": estimate | {"ratio_of_medians": 0.9},
        "estimate_320x240_paper": estimate | {"ratio_of_medians": 1.1},
        "scaling_blocks": scaling | {"ratios": [1.1, 1.143, 1.2]},
        "scaling_random": scaling
        | {"world": "random", "ratios": [0.9, 0.9, 0.9], "ratio_last_over_first": 0.9},
        "scaling_big": scaling | {"keyframes": 100000, "fallback": False, "timeout_s": 330, "last_ms": 0.85},
        "record": {
            "command": "python bench/record_bench.py --repeats 3",
            "laps": 4,
            "keyframes": 137,
            "size": "320x240",
            "repeats": 3,
            "end_to_end_keyframes_per_second": 60.7,
            "loop_keyframes_per_second": 64.3,
            "bare_keyframes_per_second": 71.1,
            "stock_keyframes_per_second": 48.9,
            "ratio_loop_over_bare": 1.1,
            "ratio_end_to_end_over_bare": 1.17,
        },
    }


@pytest.fixture
def results() -> dict[str, Any]:
    runs = {"p1": run("p1", "paper", 1), "p2": run("p2", "paper", 2), "g1": run("g1", "grid", 1)}
    runs["p2"]["methods"]["aslam"]["summary"]["loop_closure"]["precision"] = 0.25
    return {
        "quick": False,
        "started": "2026-11-29T20:00:00+00:00",
        "total_s": 421.0,
        "load_average": {"start": "0.50, 0.60, 0.70", "end": "1.00, 1.10, 1.20"},
        "machine": [["CPU", "Test CPU"], ["cores", "2 usable (2 online)"]],
        "estimator_defaults": {"search_max_states": 200},
        "tuning": {"threshold": 0.00834, "precision": 0.97, "recall": 0.86, "f1": 0.91, "seed": 1},
        "families": {
            "paper": ["p1", "p2"],
            "noise": [["p1", "p2"], ["p1"]],
            "aliasing": ["p1"],
            "routes": ["g1"],
            "long": ["g1"],
        },
        "noises": [0.03, 0.1],
        "images": ["paper-seed1-hypotheses.png"],
        "runs": runs,
        "speed": speed(),
    }


def section(text: str, heading: str) -> str:
    """The text under ``heading`` up to the next heading of any level."""
    start = text.index(heading + "\n") + len(heading) + 1
    end = text.find("\n#", start)
    return text[start : end if end >= 0 else None]


def row(text: str, first_cells: str) -> list[str]:
    """The cells of the first table row starting with ``first_cells`` ("a | b")."""
    line = next(line for line in text.splitlines() if line.startswith(f"| {first_cells} |"))
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_values_land_in_their_tables(results: dict[str, Any], tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results))
    doc = tmp_path / "out" / "benchmarks.md"
    render.render(path, doc, tmp_path / "out" / "img")
    text = doc.read_text()
    paper = section(text, "## Paper route: 10 m × 5 m rectangle, 2 laps, 3 % odometry noise, seeds 1, 2")

    header = row(paper, "method | first delay (kf)")
    aslam = dict(zip(header, row(paper, "aslam (defaults)"), strict=True))
    assert aslam["precision"] == "0.50 (0.25–0.75)"  # mean (min–max) over the two seeds
    assert aslam["recall"] == "0.50"
    assert aslam["wrong claims (all runs)"] == "8"  # summed over runs
    assert aslam["2nd-lap accuracy"] == "0.50"
    odometry = dict(zip(header, row(paper, "odometry only"), strict=True))
    assert odometry["first delay (kf)"] == "never ×2"
    assert odometry["precision"] == "no claims ×2"
    assert row(paper, "odometry only | odometry − truth")[2:] == ["0.25 / 0.75", "0.25 / 0.75", "0.2 / 0.8"]
    assert row(paper, "2")[3] == "10 / 6"  # per seed: claims / correct

    routes = section(text, "## Other routes: figure 8 and grid, 3 laps")
    assert "2nd-lap accuracy" not in routes  # no second lap off the paper route
    assert row(routes, "grid | nearest neighbour")[4] == "0.88"

    assert row(text, "estimate ÷ floor, grid route, 320×240, 2 laps")[2:] == ["1.500", "**no**"]
    assert row(text, "estimate ÷ floor, grid route, 320×240, 8 laps")[2:] == ["0.950", "yes"]
    assert row(text, "estimate ÷ floor, grid route, 640×480, 2 laps")[2:] == ["0.900", "yes"]
    assert row(text, "grid route, 320×240, 2 laps")[5] == "**1.500** (1.40–1.60)"
    assert "- Estimate ÷ floor is 1.500 on the grid route, 320×240, 2 laps recording (145 keyframes)" in text
    record = row(text, "paper | 137")
    assert record[4:7] == ["71.1 keyframes/s", "48.9 keyframes/s", "**1.10**"]  # bare, stock, ratio
    assert "Estimate ÷ floor is 0.900" not in text  # a met target gets no note
    # the libraries alone, the floor's / the estimate's, and against the floor's whole paper-route run
    assert row(text, "grid route, 320×240, 2 laps")[-1] == "0.18 / 0.42"
    assert "**The libraries alone** take 0.420 s to import in one process" in text
    assert "where the floor's own take 0.180 s" in text
    assert "which that process did not" not in text  # every library the estimate loads was imported
    # per keyframe past the fixed costs, grid 2 → 8 laps: (0.76 − 0.3) / 435 and (0.8 − 0.2) / 435 s
    assert "1.06 ms a keyframe against the floor's 1.38 ms" in text
    assert "more than one at keyframes 40–42 (at most 2, mean 1.2; back to one from keyframe 43 on)" in text
    assert "| load average (1, 5, 15 min) | at start 0.50, 0.60, 0.70; at end 1.00, 1.10, 1.20 |" in text
    assert "on 2026-11-29 20:00 UTC; the whole run took 7 min 01 s." in text
    assert (tmp_path / "out" / "img" / "long-run-drift.png").stat().st_size > 0


def test_rendering_is_deterministic(results: dict[str, Any]) -> None:
    assert render.render_text(results) == render.render_text(json.loads(json.dumps(results)))


def test_matrix_tables_appear_where_given(results: dict[str, Any]) -> None:
    def page(*names: str) -> str:
        return render.render_text(results, "img", {name: name.upper() for name in names})

    text = page("robust_matrix", "robust_held_out", "robust_mixes")
    assert text.index("ROBUST_MATRIX") < text.index("ROBUST_HELD_OUT") < text.index("ROBUST_MIXES")
    assert "### Held out: knobs mixed" in text
    assert "knobs mixed" not in page("robust_matrix", "robust_held_out")
    later = page("robust_matrix", "robust_held_out", "robust_mixes", "robust_later")
    assert later.index("ROBUST_MIXES") < later.index("ROBUST_LATER") and "seeds 9–10" in later
    assert "seeds 9–10" not in text
    latest = page(*render.ROBUST_TABLES)
    order = [latest.index(name.upper()) for name in render.ROBUST_TABLES]
    assert order == sorted(order), "the tables in the order of ROBUST_TABLES"
    assert "seeds 11–12" in latest and "seeds 11–12" not in later
    before_fresh = [name for name in render.ROBUST_TABLES if not name.startswith("robust_fresh")]
    assert "seeds 13–14" in latest and "seeds 13–14" not in page(*before_fresh)
    assert "The knob mixes and the events on other renders" in latest
    assert "The knob mixes and the events on other renders" not in page(*before_fresh, "robust_fresh")


@pytest.mark.parametrize("left_out", list(render.ROBUST_TABLES)[1:])
def test_a_table_not_made_leaves_out_its_section_and_no_other(results: dict[str, Any], left_out: str) -> None:
    """Each table after the first (the matrix, which the others extend) has a section of its own:
    without it, its heading and a ``None`` where the table would be are not on the page, and every
    other table is. Session 22's section sat under the recorder settings' condition."""
    given = [name for name in render.ROBUST_TABLES if name != left_out]
    text = render.render_text(results, "img", {name: name.upper() for name in given})
    assert "None" not in text.split()
    assert [name for name in given if name.upper() not in text] == []


def test_committed_page_is_its_committed_results_rendered() -> None:
    """docs/benchmarks.md is what `make bench-doc` makes of the committed results and tables, so a
    template edit is rendered before it is committed (the page is never edited by hand)."""
    results = json.loads(render.RESULTS.read_text())
    text = render.render_text(results, "img", render.robust_tables(render.RESULTS))
    page = render.ROOT / "docs" / "benchmarks.md"
    assert text == page.read_text(), "docs/benchmarks.md is stale: run `make bench-doc`"


def test_a_library_the_estimate_loads_but_the_bench_does_not_import_is_said(results: dict[str, Any]) -> None:
    """The libraries' figure is only a bound if it imports every library an estimate loads: the
    bench lists those it missed, and the page says its figure is low."""
    results["speed"]["estimate_320x240_paper"]["libraries_not_listed"] = ["somelib"]
    text = render.render_text(results)
    assert "but the estimate also imported somelib, which that process did not: the figure is low" in text


def test_the_start_up_targets_are_judged_on_every_bench_s_runs(results: dict[str, Any]) -> None:
    """Each estimate bench times the same one-image start-up and ``--help``: the targets take all
    their runs, not the first bench's five, and say each bench's median beside them."""
    import tables

    slow = results["speed"]["estimate_320x240"]
    slow["estimate_startup_s"] = {"median": 0.7, "min": 0.69, "max": 0.71}
    slow["estimate_startup_samples_s"] = [0.69, 0.7, 0.71]
    rows = {label: (measured, met) for label, _goal, measured, met in tables.target_rows(results["speed"])}
    measured, met = rows["`aslam estimate` start-up (one-image recording, whole process)"]
    assert measured == "0.45 s (median of 12 runs; each bench's 0.45–0.70)"
    assert met
    assert rows["`aslam --help`"] == ("0.21 s (median of 12 runs; each bench's 0.21–0.21)", True)
