"""`aslam info RECORDING.mcap [--json]`: inspect and validate a recording by reading all of it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from aslam.cli import output
from aslam.cli.app import app

if TYPE_CHECKING:
    from aslam.data_formats.recording_info import RecordingInfo


@app.command()
def info(
    recording: Annotated[
        Path,
        typer.Argument(
            help="The recording to read: our .mcap, a rosbag2 folder or file, a ROS 1 .bag.",
            show_default=False,
        ),
    ],
    json_out: Annotated[
        str | None,
        typer.Option(
            "--json",
            help="Write the description as one JSON object here; '-': stdout.",
            parser=output.output_name,
            metavar="<file>",
        ),
    ] = None,
    image_topic: output.ImageTopicOption = None,
    odometry_topic: output.OdometryTopicOption = None,
    ground_truth_topic: output.GroundTruthTopicOption = None,
    odom_frame: output.OdomFrameOption = None,
    base_frame: output.BaseFrameOption = None,
    force: output.ForceOption = False,
    quiet: output.QuietOption = False,
    verbose: output.VerboseAcceptedOption = False,
) -> None:
    """Read a recording or a ROS bag, decoding every image; print its topics, counts, duration, metadata.

    Exit 0 when the whole recording reads (warnings such as a truncated file go to stderr), 2 when not.
    """
    from aslam.app.info import describe
    from aslam.data_formats.files import check_output_path, write_text_output
    from aslam.data_formats.json_text import json_text
    from aslam.data_formats.sources import TopicChoice

    terminal = output.Terminal(quiet=quiet, verbose=verbose)
    if json_out is not None and json_out != "-":  # before reading the whole recording
        check_output_path(Path(json_out), force=force, inputs=[recording])
    topics = TopicChoice(
        image=image_topic,
        odometry=odometry_topic,
        ground_truth=ground_truth_topic,
        odom_frame=odom_frame,
        base_frame=base_frame,
    )
    with output.counted_progress(terminal, "info", unit="images") as on_progress:  # every image is decoded
        result = describe(recording, topics, on_progress=on_progress, on_warning=terminal.warning)
    if json_out is not None:
        written = write_text_output(json_out, json_text(result.as_dict(), indent=2))
        if written is not None:
            terminal.wrote(f"wrote {written}")
        return
    _print_tables(result)


def _print_tables(result: RecordingInfo) -> None:
    from rich.table import Table

    console = output.table_console()
    console.print(f"{result.path} ({result.size_bytes:,} bytes)", soft_wrap=True)  # a path, never wrapped
    topics = Table()
    topics.add_column("topic")
    topics.add_column("type")
    topics.add_column("messages", justify="right", no_wrap=True)
    for t in result.topics:
        topics.add_row(t.topic, t.datatype, str(t.messages))
    output.print_table(console, topics)

    summary = Table(show_header=False, box=None, pad_edge=False)
    summary.add_column(style="bold")
    summary.add_column()
    summary.add_row("samples", f"{result.samples} ({result.samples_with_ground_truth} with ground truth)")
    summary.add_row("duration", f"{result.duration_s:.3f} s")
    if result.first_stamp_ns is not None:
        summary.add_row("stamps", f"{result.first_stamp_ns} … {result.last_stamp_ns} ns")
    sizes = ", ".join(f"{n} × {size}" for size, n in result.image_sizes.items())
    encodings = ", ".join(f"{n} × {enc}" for enc, n in result.image_encodings.items())
    summary.add_row("images", sizes or "none")
    summary.add_row("encodings", encodings or "none")
    if result.camera is not None:
        c = result.camera
        summary.add_row(
            "camera",
            f"{c.width_px}x{c.height_px}, horizontal FOV {c.fov_deg:.2f}°, "
            f"fx={c.fx:.2f} cx={c.cx:.1f} cy={c.cy:.1f}",
        )
    assumed = result.metadata.get("odometry_known") == "false"  # an import without odometry
    path_note = " (assumed: equal steps, no odometry imported)" if assumed else ""
    summary.add_row("odometry path", f"{result.odometry_distance_m:.2f} m{path_note}")
    summary.add_row("truncated", "yes" if result.truncated else "no")
    output.print_table(console, summary)

    if result.metadata:
        meta = Table(title="metadata", title_justify="left")
        meta.add_column("key")
        meta.add_column("value", overflow="fold")
        for key, value in result.metadata.items():
            meta.add_row(key, _shortened(value))
        console.print(meta)


METADATA_SHOWN_CHARS = 400
"""A metadata value longer than this is cut in the table (a long recording's route holds every
action of every lap: 260 kB at 14,401 keyframes); ``info --json`` has it in full."""


def _shortened(value: str) -> str:
    if len(value) <= METADATA_SHOWN_CHARS:
        return value
    return f"{value[:METADATA_SHOWN_CHARS]}… ({len(value):,} characters; info --json has them all)"
