"""`aslam import FOLDER -o REC.mcap`: a folder of images (and pose files) into a recording.

The work is :func:`aslam.app.importer.import_image_folder`; this module parses and shows progress.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from aslam.cli.app import app
from aslam.cli.output import (
    ForceOption,
    QuietOption,
    Terminal,
    VerboseAcceptedOption,
    counted,
    counted_progress,
    decimal_number,
    output_file,
)
from aslam.data_formats.camera import DEFAULT_FOV_DEG
from aslam.data_formats.format_names import PoseFormat, StampUnit


@app.command("import")
def import_folder(
    folder: Annotated[
        Path, typer.Argument(help="Folder of .png/.jpg images, read in file-name order.", show_default=False)
    ],
    output: Annotated[
        Path,
        typer.Option(
            "-o", "--output", help="Recording (.mcap) to write.", parser=output_file, metavar="<file>"
        ),
    ],
    ground_truth: Annotated[
        Path | None, typer.Option(help="Pose file with the true poses (TUM, KITTI or CSV t,x,y,yaw).")
    ] = None,
    odometry: Annotated[
        Path | None,
        typer.Option(help="Pose file with the odometry. Without it: equal steps of unknown length."),
    ] = None,
    pose_format: Annotated[
        PoseFormat | None, typer.Option("--format", help="Pose-file format. \\[default: detected]")
    ] = None,
    rate_hz: Annotated[
        float | None,
        typer.Option(
            "--rate",
            parser=decimal_number,
            metavar="FLOAT",
            help="Images per second, for stamps when no pose file has them (before KITTI's times.txt).",
        ),
    ] = None,
    stamp_unit: Annotated[
        StampUnit | None,
        typer.Option(
            help="Unit of the stamps in pose files and file names. \\[default: seconds, or nanoseconds"
            " for whole numbers of 18+ digits]",
            show_default=False,
        ),
    ] = None,
    fov_deg: Annotated[
        float | None,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help=f"Horizontal field of view, degrees. \\[default: {DEFAULT_FOV_DEG:g}, recorded as assumed]",
        ),
    ] = None,
    force: ForceOption = False,
    quiet: QuietOption = False,
    verbose: VerboseAcceptedOption = False,
) -> None:
    """Import an image-folder dataset (Nordland, KITTI, TUM RGB-D, St Lucia…) as a recording."""
    from aslam.app.importer import import_image_folder

    terminal = Terminal(quiet=quiet, verbose=verbose)
    with counted_progress(terminal, "import") as on_progress:
        result = import_image_folder(
            folder,
            output,
            ground_truth=ground_truth,
            odometry=odometry,
            fmt=pose_format,
            rate_hz=rate_hz,
            stamp_unit=stamp_unit,
            fov_deg=fov_deg,
            force=force,
            on_progress=on_progress,
            on_warning=terminal.warning,
        )
    odometry_note = "odometry" if result.odometry_known else "no odometry (equal steps assumed)"
    terminal.wrote(
        f"wrote {result.output} ({result.frames} of {counted(result.images, 'image')}, "
        f"{result.width_px}x{result.height_px}, {odometry_note}"
        f"{', ground truth' if result.ground_truth else ''}; stamps {result.stamps}; {result.seconds:.1f} s)"
    )
