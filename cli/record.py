"""`aslam record`: render an indoor walkthrough with pyrender into an MCAP recording.

Thin: builds a :class:`~aslam.recorder.config.RecordConfig`, calls
:func:`aslam.recorder.record.record` with a rich progress bar, prints a one-line summary.
pyrender and cv2 are imported only when the command runs.
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
    whole_number,
)
from aslam.data_formats.camera import DEFAULT_FOV_DEG
from aslam.recorder.config import (
    DEFAULT_CAMERA_HEIGHT_M,
    NoiseModel,
    NoiseParams,
    RecordConfig,
    parse_size,
)

_DEFAULT_NOISE = NoiseParams()


@app.command()
def record(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="MCAP file to write.", parser=output_file, metavar="<file>")
    ],
    route: Annotated[
        str, typer.Option(help="Preset (paper, figure8, grid) or a route JSON file.", show_default=True)
    ] = "paper",
    laps: Annotated[
        int | None,
        typer.Option(
            parser=whole_number,
            metavar="INTEGER",
            help="Times to drive a closed route. \\[default: 2 for presets, 1 for files]",
        ),
    ] = None,
    seed: Annotated[
        int, typer.Option(parser=whole_number, metavar="INTEGER", help="Seed of the world and the noise.")
    ] = 0,
    noise: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="Odometry error per action (relative σ of distance and angle).",
        ),
    ] = _DEFAULT_NOISE.noise,
    drift_deg_per_m: Annotated[
        float,
        typer.Option(
            parser=decimal_number, metavar="FLOAT", help="Odometry heading drift σ per metre driven, degrees."
        ),
    ] = _DEFAULT_NOISE.drift_deg_per_m,
    noise_model: Annotated[
        NoiseModel,
        typer.Option(
            help="default: truth = route + jitter/wander, odometry = noisy true motion. "
            "paper: the executed actions carry the error (it accumulates in the truth; the world is "
            "built around the true path), odometry = the commanded actions.",
            case_sensitive=False,
        ),
    ] = NoiseModel.DEFAULT,
    jitter_m: Annotated[
        float | None,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="σ of the true x, y around the route, white (not accumulated), metres. "
            "(default 0.05; 0 with --noise-model paper)",
            show_default=False,
        ),
    ] = None,
    jitter_deg: Annotated[
        float | None,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="σ of the true heading around the route, white (not accumulated), degrees. "
            "(default 1.5; 0 with --noise-model paper)",
            show_default=False,
        ),
    ] = None,
    wander_m: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="σ of a smooth offset of the true x, y, correlated along the route, different on "
            "every lap (soft-limited to 0.6 m), metres.",
        ),
    ] = _DEFAULT_NOISE.wander_m,
    wander_deg: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="σ of a smooth true heading error, correlated along the route, degrees.",
        ),
    ] = _DEFAULT_NOISE.wander_deg,
    wander_length_m: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="Correlation length of the wander along the route, metres.",
        ),
    ] = _DEFAULT_NOISE.wander_length_m,
    odometry_reset_at: Annotated[
        int | None,
        typer.Option(
            parser=whole_number,
            metavar="INTEGER",
            help="Odometry restarts from zero at this keyframe (the truth goes on).",
            show_default=False,
        ),
    ] = None,
    aliasing: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="Fraction (0..1) of wall panels and floor zones drawn from a shared plain texture set; "
            "1 = every surface shared (no doors or pictures): places differ only by layout.",
        ),
    ] = 0.0,
    lighting_change: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="0..1: each lap lit differently (intensity, colour temperature, which lights are on); "
            "0 = the same light on every lap.",
        ),
    ] = 0.0,
    world: Annotated[
        Path | None,
        typer.Option(help="Scene file (.glb, .gltf, .obj; metres, +z up) instead of a generated world."),
    ] = None,
    fov_deg: Annotated[
        float, typer.Option(parser=decimal_number, metavar="FLOAT", help="Horizontal field of view, degrees.")
    ] = DEFAULT_FOV_DEG,
    size: Annotated[str, typer.Option(help="Image size WIDTHxHEIGHT.")] = "320x240",
    camera_height_m: Annotated[
        float,
        typer.Option(parser=decimal_number, metavar="FLOAT", help="Camera height above the floor, metres."),
    ] = (DEFAULT_CAMERA_HEIGHT_M),
    fps: Annotated[
        float | None,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="Render round(FPS) frames per action (1 s each). \\[default: one per action]",
        ),
    ] = None,
    jpeg_quality: Annotated[
        int | None,
        typer.Option(
            parser=whole_number, metavar="INTEGER", help="Write JPEG of this quality instead of PNG."
        ),
    ] = None,
    contact_sheet: Annotated[
        Path | None,
        typer.Option(help="Also write a PNG grid of sample keyframes.", parser=output_file, metavar="<file>"),
    ] = None,
    force: ForceOption = False,
    quiet: QuietOption = False,
    verbose: VerboseAcceptedOption = False,
) -> None:
    """Render an indoor walkthrough along a route into an MCAP recording (images, odometry, truth)."""
    width, height = parse_size(size)
    config = RecordConfig.from_options(
        route,
        laps=laps,
        seed=seed,
        noise_model=noise_model,
        noise=noise,
        drift_deg_per_m=drift_deg_per_m,
        jitter_m=jitter_m,
        jitter_deg=jitter_deg,
        wander_m=wander_m,
        wander_deg=wander_deg,
        wander_length_m=wander_length_m,
        aliasing=aliasing,
        lighting_change=lighting_change,
        odometry_reset_at=odometry_reset_at,
        world=world,
        width_px=width,
        height_px=height,
        fov_deg=fov_deg,
        camera_height_m=camera_height_m,
        fps=fps,
        jpeg_quality=jpeg_quality,
        contact_sheet=contact_sheet,
    )
    config.validate()  # before the slow imports, so bad options fail instantly

    from aslam.recorder.record import record as run_record

    terminal = Terminal(quiet=quiet, verbose=verbose)
    with counted_progress(terminal, "rendering") as on_progress:  # no bar in logs, pipes, with --quiet
        result = run_record(config, output, force=force, progress=on_progress)
    rate = result.frames / result.seconds if result.seconds > 0 else float("inf")
    terminal.wrote(
        f"wrote {result.output} ({counted(result.frames, 'frame')}, {counted(result.keyframes, 'keyframe')}, "
        f"{result.seconds:.1f} s, {rate:.0f} frames/s)"
        + (f"; contact sheet {result.contact_sheet}" if result.contact_sheet else "")
    )
