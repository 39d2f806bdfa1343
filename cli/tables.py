"""The tables `aslam report` prints: the summary, revisit errors, the hypothesis count as a sparkline."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np
    from rich.console import Console

    from aslam.app.score import Report

SPARK = "▁▂▃▄▅▆▇█"
SPARK_WIDTH = 64


# --- tables --------------------------------------------------------------------------------------


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def sparkline(counts: np.ndarray, width: int = SPARK_WIDTH) -> str:
    """The hypothesis count over the run, one character per bucket of keyframes (bucket maximum)."""
    import numpy as np

    if counts.size == 0:
        return ""
    buckets = np.array_split(counts, min(width, counts.size))
    peak = max(int(counts.max()), 1)
    return "".join(SPARK[min(len(SPARK) - 1, (int(b.max()) * len(SPARK) - 1) // peak)] for b in buckets)


def _truth_source(known: bool, recording: Path | None, first_keyframe: int) -> str:
    if not known:
        return "none"
    source = "keyframe index" if recording is None else str(recording)
    return f"{source} (and the map's sessions)" if first_keyframe else source


def _hypotheses_text(hypotheses: dict[str, Any]) -> str:
    """``max / mean / final``, or ``—`` for a run of no keyframes (its figures are null)."""
    if hypotheses["max"] is None:
        return "—"
    return "{max} / {mean:.1f} / {final}".format(**hypotheses)


def print_report(console: Console, report: Report) -> None:
    """The report's tables and the hypothesis sparkline."""
    from rich.table import Table

    from aslam.cli.output import print_table

    s = report.summary
    estimate, recording = report.estimate_path, report.recording_path
    console.print(f"aslam report — {estimate.name}", soft_wrap=True)  # a name, never wrapped
    table = Table(show_header=False)
    table.add_column("measure", style="bold")
    table.add_column("value", justify="right", no_wrap=True)
    loop = s["loop_closure"]
    reloc = s["relocalisation"]
    rows = [
        ("ground truth", _truth_source(s["ground_truth"], recording, report.estimate.graph.first_keyframe)),
        ("keyframes", s["keyframes"]),
        ("states (places)", s["states"]),
        ("links", s["links"]),
        ("loop closures claimed (best hypothesis)", loop["claims"]),
        *(
            [("  not judged (no ground truth there)", loop["unjudged_claims"])]
            if loop["unjudged_claims"]
            else []
        ),
        ("  correct", loop["correct"]),
        ("  true revisits", loop["ground_truth_revisits"]),
        ("  precision", loop["precision"]),
        ("  recall", loop["recall"]),
        ("relocalisation episodes", reloc["episodes"]),
        ("  first delay (keyframes)", reloc["first_delay_keyframes"]),
        ("  mean delay (keyframes)", reloc["mean_delay_keyframes"]),
        ("hypotheses max / mean / final", _hypotheses_text(s["hypotheses"])),
        ("trajectory APE RMSE, embedded (m)", s["trajectory"]["ape_m"]["rmse"]),
        ("  odometry alone (m)", s["trajectory"]["odometry_ape_m"]["rmse"]),
        ("  loop closures outvoted by the pose graph", s["trajectory"]["closures_outvoted"]),
        ("keyframes/s", s["timing"]["keyframes_per_second"]),
    ]
    for name, value in rows:
        table.add_row(name, _fmt(value, 1 if name == "keyframes/s" else 3))
    print_table(console, table)

    if s["ground_truth"] and recording is None:  # the truth by keyframe index
        console.print("Revisit errors: not measured (a truth by index has frame numbers, not poses)")
    elif s["ground_truth"]:
        console.print("Revisit errors (absolute; new-state hypotheses excluded)", soft_wrap=True)
        errors = Table()
        for name, justify in (
            ("error", "left"),
            ("hypothesis", "left"),
            ("mean", "right"),
            ("median", "right"),
            ("max", "right"),
        ):
            errors.add_column(name, justify=justify, no_wrap=name != "error")  # type: ignore[arg-type]
        for axis, label in (("x_m", "x (m)"), ("y_m", "y (m)"), ("heading_deg", "heading (°)")):
            for kind in ("best", "weighted"):
                stats = s["error"][kind][axis]
                errors.add_row(
                    label if kind == "best" else "",
                    "best" if kind == "best" else "belief-weighted",
                    *(_fmt(stats[stat]) for stat in ("mean", "median", "max")),
                    end_section=kind == "weighted",
                )
        print_table(console, errors)

    counts = report.evaluation.hypothesis_counts
    if not counts.size:  # no keyframes: nothing to draw
        return
    console.print(f"hypotheses over the run (max {s['hypotheses']['max']}):", highlight=False)
    console.print(f"  {sparkline(counts)}", highlight=False)
