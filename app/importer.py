"""``aslam import``: a folder of images (and pose files) into a recording, streaming.

Each image's PNG/JPEG bytes go into the recording unchanged (no re-encoding, so no quality loss and
the same input gives the same output bytes); each is also decoded once, so a corrupt file or one
of another size fails the import with its name instead of failing a later ``estimate``.

The recording's ``aslam.recording`` metadata says where everything came from, and whether the
odometry is known (``odometry_known``: ``"true"``/``"false"``). When it is not, the odometry in the
file is synthetic, ``odometry_step_m`` straight ahead per image: frames assumed equally spaced,
which ``estimate`` should treat with its motion prior for that case rather than as measured.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from aslam.core.errors import InputError
from aslam.data_formats.camera import DEFAULT_FOV_DEG
from aslam.data_formats.image_folder import (
    SYNTHETIC_STEP_M,
    ImageFolderError,
    PoseSource,
    open_image_folder,
    read_image,
)
from aslam.data_formats.pose_files import PoseFormat, StampUnit
from aslam.data_formats.provenance import tool_version

Progress = Callable[[int, int], None]  # (images done, images total)


@dataclass(frozen=True)
class ImportResult:
    """What ``import_image_folder`` wrote, and the warning lines it also gave ``on_warning``."""

    output: Path
    images: int  # in the folder
    frames: int  # written (images outside a stamped pose file's span are dropped)
    width_px: int
    height_px: int
    stamps: str  # where the stamps came from
    odometry_known: bool
    ground_truth: bool
    seconds: float
    warnings: tuple[str, ...]


def import_image_folder(
    folder: Path | str,
    output: Path | str,
    *,
    ground_truth: Path | str | None = None,
    odometry: Path | str | None = None,
    fmt: PoseFormat | str | None = None,
    rate_hz: float | None = None,
    stamp_unit: StampUnit | str | None = None,
    fov_deg: float | None = None,
    force: bool = False,
    on_progress: Progress | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> ImportResult:
    """Write the recording ``output`` from the images in ``folder`` (see ``data_formats.image_folder``
    for the order, stamps and pose pairing). Every input problem is an ``InputError`` naming the
    file (and line); nothing appears under ``output`` unless the import completes.
    """
    from aslam.data_formats.camera import CameraIntrinsics, fov_option_problem
    from aslam.data_formats.files import check_output_path, full_path, real_path
    from aslam.data_formats.images import EncodedImage, ImageFormat, JpegDamage
    from aslam.data_formats.recording_writer import RecordingWriter

    if fov_deg is not None and (problem := fov_option_problem(fov_deg)) is not None:
        raise InputError(problem)
    started = time.perf_counter()
    folder, output = Path(folder), Path(output)
    ground_truth = None if ground_truth is None else Path(ground_truth)
    odometry = None if odometry is None else Path(odometry)
    check_output_path(output, force=force)
    source = open_image_folder(
        folder, ground_truth=ground_truth, odometry=odometry, fmt=fmt, rate_hz=rate_hz, stamp_unit=stamp_unit
    )
    # Never an input, even with --force: a pose file, or a frame (found by name, the output's own or
    # the one it resolves to through a link, rather than by resolving every frame).
    names = {output.name, real_path(output).name}
    same_name = [image for image in source.images if image.name in names]
    check_output_path(output, force=True, inputs=[p for p in (odometry, ground_truth) if p] + same_name)
    first = source.images[0]
    height_px, width_px = read_image(first).decode_gray().shape
    camera = CameraIntrinsics(width_px, height_px, DEFAULT_FOV_DEG if fov_deg is None else fov_deg)
    warnings: list[str] = []

    def warn(line: str) -> None:
        warnings.append(line)
        if on_warning is not None:
            on_warning(line)

    def describe(pose_source: PoseSource | None) -> str:
        if pose_source is None:
            return "none"
        return f"{full_path(pose_source.path)} ({pose_source.format.value}, {pose_source.rows} poses)"

    metadata = {
        "source": "image-folder",
        "folder": str(full_path(folder)),
        "images": str(len(source)),
        "stamps": source.stamps,
        "odometry_known": "true" if source.odometry_known else "false",
        "odometry": describe(source.odometry),
        "ground_truth": describe(source.ground_truth),
        "camera": json.dumps(
            {
                "width_px": width_px,
                "height_px": height_px,
                "fov_deg": camera.fov_deg,
                "fov_known": fov_deg is not None,
            },
            separators=(",", ":"),
        ),
        "tool_version": tool_version(),
    }
    if not source.odometry_known:
        metadata["odometry_step_m"] = f"{SYNTHETIC_STEP_M:g}"
    total = len(source)
    done = 0
    damage = JpegDamage()
    with RecordingWriter(output, camera=camera, metadata=metadata, force=force) as writer:
        for sample in source.samples(on_warning=warn):
            image = sample.image
            shape = damage.decode_gray(image).shape  # decoded once: a corrupt file fails here, named
            if shape != (height_px, width_px):
                raise ImageFolderError(
                    f"is {shape[1]}x{shape[0]} but {first.name} (the first image) is {width_px}x{height_px}",
                    path=image.path,
                )
            writer.write(
                sample.stamp_ns,
                EncodedImage(ImageFormat(image.encoding), image.data),
                sample.odometry_pose,
                sample.ground_truth_pose,
            )
            done += 1
            if on_progress is not None:
                on_progress(done, total)
        if done == 0:  # a recording of no frames: estimate would find no image topic in it
            within = "the odometry" if source.odometry is None else source.odometry.path.name
            raise ImageFolderError(
                f"none of its {total} images is stamped within {within} (the images' stamps: "
                f"{source.stamps}); nothing to import",
                path=folder,
            )
    if (line := damage.warning(Path(folder), done)) is not None:
        warn(line)
    return ImportResult(
        output=output,
        images=total,
        frames=done,
        width_px=width_px,
        height_px=height_px,
        stamps=source.stamps,
        odometry_known=source.odometry_known,
        ground_truth=source.ground_truth is not None,
        seconds=time.perf_counter() - started,
        warnings=tuple(warnings),
    )
