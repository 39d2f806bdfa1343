"""Table rows and aggregates of the benchmark document, computed from the results JSON.

Every function takes runs as stored by ``bench/run_all.py`` (``results["runs"][name]``) and returns
cells as text; the words around them live in ``bench/templates/benchmarks.md``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

Run = dict[str, Any]
METHODS = ("aslam", "paper-faithful", "nearest", "odometry")
METHOD_NAMES = {
    "aslam": "aslam (defaults)",
    "paper-faithful": "aslam `--paper-faithful`",
    "nearest": "nearest neighbour",
    "odometry": "odometry only",
}


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


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def get(run: Run, method: str, dotted: str) -> Any:
    """A value of ``method``'s summary on ``run`` by dotted key ("loop_closure.precision")."""
    value: Any = run["methods"][method]["summary"]
    for key in dotted.split("."):
        value = value[key]
    return value


def summaries(runs: list[Run], method: str, dotted: str) -> list[Any]:
    """A summary value of ``method`` over ``runs`` (what ``aslam report --json`` says)."""
    return [get(r, method, dotted) for r in runs]


def scores(runs: list[Run], method: str, key: str) -> list[Any]:
    """A score the bench adds to the summary (``f1``, ``wrong_claims``, ``wall_s`` ...) over ``runs``."""
    return [r["methods"][method][key] for r in runs]


def mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def has_second_lap(runs: list[Run]) -> bool:
    return any(r["scenario"]["second_lap_from"] is not None for r in runs)


def labelled(method: str, label: str | None) -> list[str]:
    return [METHOD_NAMES[method]] if label is None else [label, METHOD_NAMES[method]]


def loop_closing_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    rows = []
    for method in METHODS:
        row = [
            *labelled(method, label),
            agg(summaries(runs, method, "relocalisation.first_delay_keyframes"), 1, "never"),
            agg(summaries(runs, method, "relocalisation.mean_delay_keyframes"), 1, "never"),
            agg(summaries(runs, method, "loop_closure.precision"), 2, "no claims"),
            agg(summaries(runs, method, "loop_closure.recall")),
            agg(scores(runs, method, "f1")),
            str(sum(scores(runs, method, "wrong_claims"))),
            str(sum(scores(runs, method, "missed_revisits"))),
        ]
        if has_second_lap(runs):
            row.append(agg(scores(runs, method, "second_lap_accuracy")))
        rows.append(row)
    return rows


def error_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    """Rows per method and kind (best, belief-weighted): x, y, heading error mean / max."""

    def cells(stats: list[dict[str, dict[str, float | None]]]) -> list[str]:
        out = []
        for axis in ("x_m", "y_m", "heading_deg"):
            digits = 1 if axis == "heading_deg" else 2
            means, highs = [s[axis]["mean"] for s in stats], [s[axis]["max"] for s in stats]
            out.append(f"{agg(means, digits)} / {agg(highs, digits)}")
        return out

    rows = []
    for method, kinds in (
        ("aslam", (("best", "best"), ("weighted", "belief-weighted"))),
        ("paper-faithful", (("best", "best"), ("weighted", "belief-weighted"))),
        ("nearest", (("best", "best (the only hypothesis)"),)),
    ):
        for kind, name in kinds:
            rows.append([*labelled(method, label), name, *cells(summaries(runs, method, f"error.{kind}"))])
    rows.append(
        [*labelled("odometry", label), "odometry − truth", *cells([r["drift"]["error"] for r in runs])]
    )
    return rows


def cost_rows(runs: list[Run], label: str | None = None) -> list[list[str]]:
    return [
        [
            *labelled(method, label),
            agg(summaries(runs, method, "states"), 0),
            agg(summaries(runs, method, "hypotheses.max"), 0),
            agg(summaries(runs, method, "hypotheses.mean"), 1),
            agg(summaries(runs, method, "timing.keyframes_per_second"), 0),
            agg(scores(runs, method, "wall_s"), 2),
            agg(scores(runs, method, "peak_rss_mib"), 0),
        ]
        for method in ("aslam", "paper-faithful")
    ]


def per_seed_rows(runs: list[Run]) -> list[list[str]]:
    """The paper route seed by seed, project defaults (and two `--paper-faithful` columns)."""
    rows = []
    for r in runs:
        s = r["methods"]["aslam"]["summary"]
        rows.append(
            [
                str(r["scenario"]["seed"]),
                str(s["keyframes"]),
                str(s["loop_closure"]["ground_truth_revisits"]),
                f"{s['loop_closure']['claims']} / {s['loop_closure']['correct']}",
                fmt(s["loop_closure"]["precision"]),
                fmt(s["loop_closure"]["recall"]),
                fmt(s["relocalisation"]["first_delay_keyframes"]),
                fmt(s["relocalisation"]["mean_delay_keyframes"], 1),
                fmt(r["methods"]["aslam"]["second_lap_accuracy"]),
                f"{s['hypotheses']['max']} / {s['hypotheses']['mean']:.1f}",
                fmt(get(r, "paper-faithful", "loop_closure.recall")),
                fmt(r["methods"]["paper-faithful"]["second_lap_accuracy"]),
                f"{r['drift']['final_m']:.2f} / {r['drift']['max_m']:.2f}",
            ]
        )
    return rows


def noise_rows(noise_runs: list[tuple[float, list[Run]]]) -> list[list[str]]:
    """Loop closing per σ, the odometry drift in the first row of each block."""
    rows = []
    for noise, runs in noise_runs:
        block = loop_closing_rows(runs, f"{noise:g}")
        block[0].append(f"{agg(drift_values(runs, 'final_m'))} / {agg(drift_values(runs, 'max_m'))}")
        for row in block[1:]:
            row.append("")
        rows += block
    return rows


def drift_values(runs: list[Run], key: str) -> list[float]:
    return [r["drift"][key] for r in runs]


def met(ok: bool) -> str:
    return "met" if ok else "**not met**"


ESTIMATES = (
    ("estimate_320x240", "grid route, 320×240, 2 laps"),
    ("estimate_320x240_long", "grid route, 320×240, 8 laps"),
    ("estimate_640x480", "grid route, 640×480, 2 laps"),
    ("estimate_320x240_paper", "paper route, 320×240, 2 laps"),
)
STAGES = (
    "read_and_sync_s",
    "decode_s",
    "describe_s",
    "slam_s",
    "metric_view_imports_s",
    "metric_view_s",
    "write_s",
    "sha256_s",
)


def estimate_rows(speed: dict[str, Any]) -> list[list[str]]:
    """The ``aslam estimate`` process against the independent floor, medians of alternating runs."""
    rows = []
    for key, label in ESTIMATES:
        d = speed[key]
        pairs = d["pair_ratio"]
        recording = [label, f"{d['size_mb']:.1f}", str(d["stages"]["keyframes"])]
        seconds = [f"{d[name]['median']:.3f}" for name in ("floor_s", "estimate_s")]
        ratio = f"**{d['ratio_of_medians']:.3f}** ({pairs['min']:.2f}–{pairs['max']:.2f})"
        verdict = [ratio, met(d["ratio_of_medians"] <= 1.0), f"{d['keyframes_per_second']:.0f}"]
        startup = [f"{d['estimate_startup_s']['median']:.2f}", f"{d['help_s']['median']:.2f}"]
        startup.append(f"{d['floor_libraries_s']['median']:.2f} / {d['estimate_libraries_s']['median']:.2f}")
        rows.append([*recording, *seconds, *verdict, *startup])
    return rows


def stage_rows(speed: dict[str, Any]) -> list[list[str]]:
    """Each stage of an estimate alone, in-process, one thread: where the time goes."""
    return [[label, *(f"{speed[key]['stages'][stage]:.3f}" for stage in STAGES)] for key, label in ESTIMATES]


def scaling_rows(speed: dict[str, Any]) -> list[list[str]]:
    rows = []
    for key in ("scaling_blocks", "scaling_random", "scaling_big"):
        d = speed[key]
        ratio = f"**{d['ratio_last_over_first']:.2f}**"
        if "ratios" in d:
            ratio += f" (median of {len(d['ratios'])}: " + ", ".join(f"{x:.2f}" for x in d["ratios"]) + ")"
        rows.append(
            [
                d["world"],
                f"{d['keyframes']:,}",
                f"{d['states']:,}",
                f"{d['first_ms']:.3f} ({d['first_ms_at_start']:.3f})",
                f"{d['last_ms']:.3f}",
                ratio,
                met(d["ratio_last_over_first"] <= SCALING_TARGET),
                "—"
                if d.get("second_ms") is None
                else f"{d['second_ms']:.3f}: {d['ratio_last_over_second']:.2f}",
                f"{d['hypotheses_mean']:.2f} / {d['hypotheses_max']}",
                f"{d['searched_states_mean']:.0f}",
                f"{d['peak_rss_mib']:.0f}",
                f"{d['bench_wall_s']:.0f}",
            ]
        )
    return rows


SCALING_TARGET = 1.2
RECORD_KEYFRAMES_PER_SECOND = 40
RECORD_RATIO = 1.2
RECORD_WORLDS = ("record", "record_grid")
"""The keys of the record benches: the paper world and a generated grid world."""


def pooled(speed: dict[str, Any], key: str) -> tuple[float, int, float, float]:
    """One command timed in every estimate bench (``help`` or ``estimate_startup``), all its runs
    together: (median, runs, the lowest and highest bench's median). The benches run the same
    command, so their runs are one sample; one bench's few were at the mercy of its moment."""
    samples = [x for name, _ in ESTIMATES for x in speed[name][f"{key}_samples_s"]]
    medians = [speed[name][f"{key}_s"]["median"] for name, _ in ESTIMATES]
    return float(np.median(samples)), len(samples), min(medians), max(medians)


def target_rows(speed: dict[str, Any]) -> list[tuple[str, str, str, bool]]:
    """(target, goal, measured, met) for every speed and memory target."""
    big = speed["scaling_big"]
    rows = [
        (f"estimate ÷ floor, {label}", "≤ 1.0", f"{d['ratio_of_medians']:.3f}", d["ratio_of_medians"] <= 1.0)
        for d, label in ((speed[key], label) for key, label in ESTIMATES)
    ]
    for label, key, goal in (
        ("`aslam --help`", "help", 0.3),
        ("`aslam estimate` start-up (one-image recording, whole process)", "estimate_startup", 0.5),
    ):
        median, runs, low, high = pooled(speed, key)
        measured = f"{median:.2f} s (median of {runs} runs; each bench's {low:.2f}–{high:.2f})"
        rows.append((label, f"≤ {goal} s", measured, median <= goal))
    rows += [
        (
            f"SLAM step, last ÷ first 1,000, {d['world']} ({d['keyframes']:,})",
            f"≤ {SCALING_TARGET}",
            f"{d['ratio_last_over_first']:.2f}",
            d["ratio_last_over_first"] <= SCALING_TARGET,
        )
        for d in (speed["scaling_blocks"], speed["scaling_random"], big)
    ]
    rows.append(
        (
            f"peak memory, {big['keyframes']:,} keyframes",
            "< 1 GiB",
            f"{big['peak_rss_mib']:.0f} MiB",
            big["peak_rss_mib"] < 1024,
        )
    )
    for key in RECORD_WORLDS:
        rec = speed.get(key)
        if rec is None:
            continue
        loop, end_to_end = rec["loop_keyframes_per_second"], rec["end_to_end_keyframes_per_second"]
        world = rec.get("route", "paper")
        rows += [
            (
                f"record, {world} world, keyframes/s (record loop / end-to-end)",
                f"≥ {RECORD_KEYFRAMES_PER_SECOND}",
                f"{loop:.1f} / {end_to_end:.1f}",
                loop >= RECORD_KEYFRAMES_PER_SECOND,
            ),
            (
                f"record loop ÷ bare pyrender loop, {world} world (end-to-end ÷ bare)",
                f"≤ {RECORD_RATIO}",
                f"{rec['ratio_loop_over_bare']:.2f} ({rec['ratio_end_to_end_over_bare']:.2f})",
                rec["ratio_loop_over_bare"] <= RECORD_RATIO,
            ),
        ]
    return rows


def near_target(goal: str, measured: str) -> bool:
    """A ratio target missed by less than 5 % ("≤ 1.25" against "1.257")."""
    try:
        target = float(goal.split()[-1])
        value = float(measured.split()[0])
    except ValueError:
        return False
    return goal.startswith("≤") and value <= target * 1.05


def spans(mask: np.ndarray) -> list[str]:
    """['38–43', '50–52'] for the runs of True in ``mask``."""
    from aslam.core.metrics import true_runs

    return [str(start) if stop - 1 == start else f"{start}–{stop - 1}" for start, stop in true_runs(mask)]
