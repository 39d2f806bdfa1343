"""`aslam report ESTIMATE.mcap`: tables, graph JSON, plots, summary JSON and quality gates."""

from __future__ import annotations

import json
import sys
from contextlib import closing
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from aslam.cli.app import app
from aslam.core.errors import InputError, QualityGateFailed

if TYPE_CHECKING:
    import numpy as np
    from rich.console import Console

    from aslam.core.metrics import Evaluation

SPARK = "▁▂▃▄▅▆▇█"
SPARK_WIDTH = 64


def _warning_line(message: str) -> None:
    sys.stderr.write(f"aslam: warning: {' '.join(message.split())}\n")
    sys.stderr.flush()


@app.command()
def report(
    estimate: Annotated[
        Path, typer.Argument(help="Estimate file (.mcap) written by 'aslam estimate'.", show_default=False)
    ],
    recording: Annotated[
        Path | None,
        typer.Option(
            help="Recording with the ground truth. \\[default: the one named in the estimate]",
            dir_okay=False,
        ),
    ] = None,
    graph: Annotated[
        Path | None,
        typer.Option("--graph", help="Write the map as JSON (docs/graph-json.md).", dir_okay=False),
    ] = None,
    plots: Annotated[
        Path | None, typer.Option("--plots", help="Write PNG figures into this folder.", file_okay=False)
    ] = None,
    json_out: Annotated[
        str | None,
        typer.Option(
            "--json", help="Write the summary JSON here ('-': stdout; the tables then go to stderr)."
        ),
    ] = None,
    fail_on: Annotated[
        list[str] | None,
        typer.Option(
            "--fail-on",
            help="Exit 1 if KEY OP NUMBER holds, e.g. 'loop_closure.precision<0.99' (repeatable).",
            show_default=False,
        ),
    ] = None,
    radius_m: Annotated[
        float, typer.Option(help="A revisit is within this distance of the earlier true position (m).")
    ] = 0.5,
    heading_deg: Annotated[
        float, typer.Option(help="A revisit is within this difference of the earlier true heading (degrees).")
    ] = 45.0,
) -> None:
    """Score an estimate against the recording's ground truth: tables, graph JSON, plots, gates.

    Without ground truth (no recording found) it reports what needs none.

    Exit 1 when a --fail-on condition holds; a null value (not measurable) fails the gate.
    """
    from aslam.data_formats.report import parse_condition, summary_keys

    keys = summary_keys()
    conditions = [parse_condition(text, keys) for text in fail_on or []]
    if not radius_m > 0:
        raise InputError(f"--radius-m must be positive, got {radius_m}")
    if not 0 < heading_deg <= 180:
        raise InputError(f"--heading-deg must be in (0, 180], got {heading_deg}")
    for path in [graph] + ([Path(json_out)] if json_out not in (None, "-") else []):
        if path is not None and not path.parent.is_dir():
            raise InputError(f"folder {path.parent} does not exist", path=path)
    if plots is not None and plots.exists() and not plots.is_dir():
        raise InputError("exists and is not a folder", path=plots)
    run_report(
        estimate,
        recording=recording,
        graph_path=graph,
        plots=plots,
        json_out=json_out,
        conditions=conditions,
        radius_m=radius_m,
        heading_deg=heading_deg,
    )


def run_report(
    estimate: Path,
    *,
    recording: Path | None,
    graph_path: Path | None,
    plots: Path | None,
    json_out: str | None,
    conditions: list[Any],
    radius_m: float,
    heading_deg: float,
) -> None:
    import numpy as np
    from rich.console import Console

    from aslam.core.metrics import evaluate
    from aslam.data_formats.estimate import iter_keyframes, read_estimate
    from aslam.data_formats.files import write_atomically
    from aslam.data_formats.report import build_graph_json, build_summary, failed_conditions

    info = read_estimate(estimate)
    steps = []
    stamps: list[int] = []
    actions = []
    with closing(iter_keyframes(estimate)) as keyframes:
        for keyframe in keyframes:
            steps.append((keyframe.index, keyframe.hypotheses))
            stamps.append(keyframe.stamp_ns)
            actions.append(keyframe.action)
    action_array = np.array(actions, dtype=float).reshape(-1, 3)

    recording_path = _find_recording(
        recording, info.metadata.recording.path, info.metadata.recording.size_bytes
    )
    true_poses = None
    if recording_path is not None:
        true_poses = _ground_truth(recording_path, info.metadata.topics, stamps)

    evaluation = evaluate(steps, true_poses, radius_m=radius_m, heading_deg=heading_deg)
    if not evaluation.has_ground_truth:
        true_poses = None
    kps = info.timing.keyframes_per_second if info.timing is not None else None
    summary = build_summary(
        evaluation, states=len(info.graph["states"]), links=len(info.graph["links"]), keyframes_per_second=kps
    )

    console = Console(file=sys.stderr if json_out == "-" else sys.stdout, soft_wrap=False)
    _print_tables(console, summary, evaluation, estimate, recording_path)

    if graph_path is not None:
        document = build_graph_json(
            info.graph,
            stamps,
            true_poses,
            estimate_path=str(estimate.absolute()),
            recording_path=None if recording_path is None else str(recording_path),
        )
        write_atomically(graph_path, lambda p: p.write_text(json.dumps(document, indent=1) + "\n"))
    if plots is not None:
        from aslam.cli.plots import write_plots

        write_plots(plots, evaluation, info.graph, action_array, true_poses, title=estimate.name)
    if json_out == "-":
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
        sys.stdout.flush()
    elif json_out is not None:
        text = json.dumps(summary, indent=2) + "\n"
        write_atomically(Path(json_out), lambda p: p.write_text(text))

    failed = failed_conditions(conditions, summary)
    if failed:
        raise QualityGateFailed(f"quality gate failed: {'; '.join(failed)}")


def _find_recording(given: Path | None, named: str, size_bytes: int) -> Path | None:
    """The recording to take ground truth from, or None (with one warning line) if it is missing."""
    if given is not None:
        if not given.is_file():
            raise InputError("no such recording", path=given)
        return given.absolute()
    path = Path(named)
    if not path.is_file():
        _warning_line(f"recording {named} (named in the estimate) not found; reporting without ground truth")
        return None
    if path.stat().st_size != size_bytes:
        _warning_line(
            f"recording {named} has changed since the estimate "
            f"({path.stat().st_size} bytes, was {size_bytes})"
        )
    return path


def _ground_truth(path: Path, topics: dict[str, str], stamps: list[int]) -> np.ndarray | None:
    from aslam.data_formats.recording import RecordingError, RecordingTopics, iter_ground_truth
    from aslam.data_formats.report import truth_at_stamps

    defaults = RecordingTopics()
    chosen = RecordingTopics(
        image=topics.get("image", defaults.image),
        odometry=topics.get("odometry", defaults.odometry),
        ground_truth=topics.get("ground_truth", defaults.ground_truth),
        camera_info=topics.get("camera_info", defaults.camera_info),
    )
    try:
        with closing(iter_ground_truth(path, chosen, on_warning=_warning_line)) as truth:  # type: ignore[arg-type]
            poses = truth_at_stamps(stamps, truth)
    except RecordingError as err:
        _warning_line(f"{err}; reporting without ground truth")
        return None
    if not len(poses) or not (poses == poses).all(axis=1).any():
        _warning_line(f"{path}: no ground truth at the keyframe stamps; reporting without ground truth")
        return None
    return poses


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


def _print_tables(
    console: Console, summary: dict[str, Any], evaluation: Evaluation, estimate: Path, recording: Path | None
) -> None:
    from rich.table import Table

    s = summary
    table = Table(title=f"aslam report — {estimate.name}", show_header=False, title_justify="left")
    table.add_column("measure", style="bold")
    table.add_column("value", justify="right")
    loop = s["loop_closure"]
    reloc = s["relocalisation"]
    rows = [
        ("ground truth", str(recording) if s["ground_truth"] else "none"),
        ("keyframes", s["keyframes"]),
        ("states (places)", s["states"]),
        ("links", s["links"]),
        ("loop closures claimed (best hypothesis)", loop["claims"]),
        ("  correct", loop["correct"]),
        ("  true revisits", loop["ground_truth_revisits"]),
        ("  precision", loop["precision"]),
        ("  recall", loop["recall"]),
        ("relocalisation episodes", reloc["episodes"]),
        ("  first delay (keyframes)", reloc["first_delay_keyframes"]),
        ("  mean delay (keyframes)", reloc["mean_delay_keyframes"]),
        ("hypotheses max / mean / final", "{max} / {mean:.1f} / {final}".format(**s["hypotheses"])),
        ("keyframes/s", s["timing"]["keyframes_per_second"]),
    ]
    for name, value in rows:
        table.add_row(name, _fmt(value, 1 if name == "keyframes/s" else 3))
    console.print(table)

    if s["ground_truth"]:
        errors = Table(title="Revisit errors (absolute; new-state hypotheses excluded)", title_justify="left")
        for name, justify in (
            ("error", "left"),
            ("hypothesis", "left"),
            ("mean", "right"),
            ("median", "right"),
            ("max", "right"),
        ):
            errors.add_column(name, justify=justify)  # type: ignore[arg-type]
        for axis, label in (("x_m", "x (m)"), ("y_m", "y (m)"), ("heading_deg", "heading (°)")):
            for kind in ("best", "weighted"):
                stats = s["error"][kind][axis]
                errors.add_row(
                    label if kind == "best" else "",
                    "best" if kind == "best" else "belief-weighted",
                    *(_fmt(stats[stat]) for stat in ("mean", "median", "max")),
                    end_section=kind == "weighted",
                )
        console.print(errors)

    counts = evaluation.hypothesis_counts
    console.print(f"hypotheses over the run (max {s['hypotheses']['max']}):", highlight=False)
    console.print(f"  {sparkline(counts)}", highlight=False)
