"""The recorder's entry point: config → route → world → noisy poses → rendered frames → MCAP.

:func:`record` is a plain function; the CLI only builds the :class:`RecordConfig`, drives the
progress callback with rich, and maps errors to exit codes.
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aslam.core import se2
from aslam.core.errors import ConfigError, InputError
from aslam.data_formats.provenance import tool_version
from aslam.recorder import noise, routes
from aslam.recorder.config import NoiseModel, RecordConfig
from aslam.recorder.errors import RouteError
from aslam.recorder.lighting import DEFAULT as DEFAULT_LIGHTING
from aslam.recorder.lighting import Lighting, lap_lighting, lighting_json
from aslam.recorder.world import (
    TRUE_PATH,
    TRUE_PATH_CLEARANCE_M,
    GridWorld,
    SceneWorld,
    check_path_in_world,
    check_route_in_scene,
    generate_world,
    load_scene_world,
)

#: Stamps start at a fixed epoch (2020-09-13T12:26:40Z), not at 0 (which ROS tools treat as unset),
#: and not at the wall clock (which would break byte-identical output).
START_STAMP_NS = 1_600_000_000_000_000_000
ACTION_DURATION_NS = 1_000_000_000
#: Frames rendered ahead of the encoder/writer thread (bounds memory, keeps both busy).
MAX_IN_FLIGHT = 4
CONTACT_SHEET_FRAMES = 24

Progress = Callable[[int, int], None]  # (frames done, frames total)


class Frame(NamedTuple):
    """One image to render: when, where it really is, where odometry says, its keyframe and lighting."""

    stamp_ns: int
    truth_pose: np.ndarray
    odometry_pose: np.ndarray
    keyframe: int | None  # index of the keyframe, None for intermediate (--fps) frames
    lighting: Lighting = DEFAULT_LIGHTING


@dataclass(frozen=True)
class Plan:
    """Everything decided before rendering: route, world, poses, lighting.

    ``odometry`` is what ``/odom`` reports at each keyframe (after any reset);
    ``odometry_before_reset`` is pose ``odometry_reset_at`` in the old frame, so the frames of the
    action that leads to the reset interpolate in the frame they belong to.
    """

    route: routes.Route
    world: GridWorld | SceneWorld
    truth: np.ndarray  # keyframe poses, (n, 3)
    odometry: np.ndarray  # keyframe poses, (n, 3)
    frames_per_action: int
    lightings: tuple[Lighting, ...] = (DEFAULT_LIGHTING,)  # one per lap
    lap_of_keyframe: np.ndarray | None = None  # (n,) lap index of each keyframe
    odometry_reset_at: int | None = None
    odometry_before_reset: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return (len(self.truth) - 1) * self.frames_per_action + 1

    def _lighting(self, k: int) -> Lighting:
        lap = 0 if self.lap_of_keyframe is None else int(self.lap_of_keyframe[k])
        return self.lightings[lap]

    def frames(self) -> Iterator[Frame]:
        n = self.frames_per_action
        connected = self.route.connected
        for k in range(len(self.truth) - 1):
            lighting = self._lighting(k)
            odom_next = self.odometry[k + 1]
            if self.odometry_reset_at == k + 1 and self.odometry_before_reset is not None:
                odom_next = self.odometry_before_reset
            for j in range(n):
                stamp = START_STAMP_NS + k * ACTION_DURATION_NS + j * ACTION_DURATION_NS // n
                if j == 0:
                    yield Frame(stamp, self.truth[k], self.odometry[k], k, lighting)
                elif not connected[k]:  # carried away: the view and odometry hold until set down
                    yield Frame(stamp, self.truth[k], self.odometry[k], None, lighting)
                else:
                    f = j / n
                    turn = self.route.actions[k].turn_rad  # both turn the way commanded, however far
                    truth = se2.interpolate(self.truth[k], self.truth[k + 1], f, turn)
                    odom = se2.interpolate(self.odometry[k], odom_next, f, turn)
                    yield Frame(stamp, truth, odom, None, lighting)
        k = len(self.truth) - 1
        yield Frame(
            START_STAMP_NS + k * ACTION_DURATION_NS, self.truth[k], self.odometry[k], k, self._lighting(k)
        )


@dataclass(frozen=True)
class RecordResult:
    """What ``record`` wrote: the recording (and contact sheet), its image counts and timings."""

    output: Path
    frames: int
    """Images written: the keyframes' and, with ``fps``, the frames between them."""
    keyframes: int
    """Poses of the route: its start and one after each action."""
    seconds: float
    render_seconds: float  # the render/encode/write loop only (excludes world building, GL start-up)
    contact_sheet: Path | None


def driven_route(config: RecordConfig) -> tuple[routes.Route, int, routes.Route]:
    """(the route, its laps, the route as driven: every lap): what :func:`plan` refuses before any
    world is built (the config's values, the route file, laps of an open route, the action cap, a
    reset beyond the route), cheap enough for a sweep file's check of every render."""
    config.validate()
    base = routes.resolve_route(config.route)
    laps = routes.default_laps(config.route) if config.laps is None else config.laps
    try:
        route = base.repeated(laps)
    except RouteError as err:  # the file named, not only the route's name (its stem)
        if err.path is not None or config.route in routes.PRESETS:
            raise
        raise RouteError(err.problem, path=config.route) from err
    keyframes = len(route.actions) + 1
    reset_at = config.odometry_reset_at
    if reset_at is not None and reset_at >= keyframes:
        raise ConfigError(
            f"--odometry-reset-at must be a keyframe of the route (0..{keyframes - 1}), got {reset_at}"
        )
    return base, laps, route


def plan(config: RecordConfig) -> Plan:
    """Validate the config, resolve the route, simulate the poses, build or load the world.

    The generated world is built around the commanded path, and with ``--noise-model paper``
    (whose truth drifts off the route) around the true path as well; either way the true path is
    then checked to stay in free space, naming the first action that leaves it.
    """
    base, laps, route = driven_route(config)
    commanded = route.poses()
    connected = route.connected
    actions_json = [a.to_json() for a in route.actions]
    reset_at = config.odometry_reset_at
    truth, odometry = noise.simulate(commanded, config.noise, config.seed, connected=connected)
    world: GridWorld | SceneWorld
    if config.world is None:
        drifting = config.noise.model is NoiseModel.PAPER
        world = generate_world(
            commanded,
            config.seed,
            aliasing=config.aliasing,
            connected=connected,
            true_path=truth if drifting else None,
        )
        # a pose no driven step reaches (a route that starts or ends with a kidnap) has no corridor
        check_path_in_world(
            world,
            commanded,
            actions_json,
            connected=connected,
            what="the route (only driven steps get corridors)",
        )
        check_path_in_world(world, truth, actions_json, connected=connected)
        n_lights = len(world.lights_xy)
    else:
        world = load_scene_world(config.world)
        check_route_in_scene(world, commanded, actions_json, config.camera.height_m, connected=connected)
        check_route_in_scene(
            world,
            truth,
            actions_json,
            config.camera.height_m,
            clearance_m=TRUE_PATH_CLEARANCE_M,
            connected=connected,
            what=TRUE_PATH,
        )
        n_lights = 0
    before_reset = None
    if reset_at is not None:
        before_reset = odometry[reset_at].copy()
        odometry = noise.reset_odometry(odometry, reset_at)
    per_lap = len(base.actions)
    lap_of_keyframe = np.minimum(np.arange(len(commanded)) // per_lap, laps - 1)
    lightings = lap_lighting(config.lighting_change, laps, n_lights, config.seed)
    return Plan(
        route,
        world,
        truth,
        odometry,
        config.frames_per_action,
        lightings=lightings,
        lap_of_keyframe=lap_of_keyframe,
        odometry_reset_at=reset_at,
        odometry_before_reset=before_reset,
    )


def metadata(config: RecordConfig, p: Plan) -> dict[str, str]:
    camera = {**asdict(config.camera), "frames_per_action": p.frames_per_action}
    if config.jpeg_quality is not None:  # PNG recordings keep the bytes they had
        camera["jpeg_quality"] = config.jpeg_quality
    return {
        "world": p.world.describe(),
        "seed": str(config.seed),
        "route": p.route.to_json(),
        "noise": noise.noise_json(config.noise, odometry_reset_at=config.odometry_reset_at),
        "lighting": lighting_json(config.lighting_change, p.lightings),
        "camera": json.dumps(camera, separators=(",", ":")),
        "tool_version": tool_version(),
    }


def record(
    config: RecordConfig, output: Path | str, *, force: bool = False, progress: Progress | None = None
) -> RecordResult:
    """Render the recording described by ``config`` into ``output`` (an MCAP file).

    The writer writes to a temporary name and renames it when complete, so an error or Ctrl-C
    leaves nothing under ``output``.  Rendering runs in this thread; PNG/JPEG encoding and writing
    run in one helper thread, in frame order, so the output is deterministic.
    """
    from aslam.data_formats.camera import CameraIntrinsics
    from aslam.data_formats.files import check_output_path
    from aslam.data_formats.images import ImageFormat, encode_image
    from aslam.data_formats.recording_writer import RecordingWriter
    from aslam.recorder.render import PyrenderRenderer

    started = time.perf_counter()
    output = Path(output)
    # The writers check too; failing here skips the slow set-up. No output may be an input, or both.
    inputs = [Path(p) for p in (config.route, config.world) if p is not None and Path(p).is_file()]
    check_output_path(output, force=force, inputs=inputs)
    if config.contact_sheet is not None:
        check_output_path(config.contact_sheet, force=force, inputs=inputs, outputs=[output])
    p = plan(config)
    cam = config.camera
    intrinsics = CameraIntrinsics(width_px=cam.width_px, height_px=cam.height_px, fov_deg=cam.fov_deg)
    fmt = ImageFormat.PNG if config.jpeg_quality is None else ImageFormat.JPEG
    quality = 90 if config.jpeg_quality is None else config.jpeg_quality
    total = p.n_frames
    sheet_keys = set(_sheet_keyframes(len(p.truth)))
    sheet: list[tuple[int, np.ndarray]] = []

    with PyrenderRenderer(p.world, cam, p.lightings) as renderer:
        loop_start = time.perf_counter()
        with (
            RecordingWriter(output, camera=intrinsics, metadata=metadata(config, p), force=force) as writer,
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="aslam-encode") as pool,
        ):

            def encode_and_write(frame: Frame, rgb: np.ndarray) -> None:
                writer.write(
                    frame.stamp_ns, encode_image(rgb, fmt, quality), frame.odometry_pose, frame.truth_pose
                )

            pending: deque[Future] = deque()
            done = 0
            try:
                for frame in p.frames():
                    rgb = renderer.render(frame.truth_pose, frame.lighting)
                    if frame.keyframe in sheet_keys:
                        sheet.append((frame.keyframe, rgb))
                    pending.append(pool.submit(encode_and_write, frame, rgb))
                    while len(pending) > MAX_IN_FLIGHT or (pending and pending[0].done()):
                        pending.popleft().result()
                        done += 1
                        if progress is not None:
                            progress(done, total)
                while pending:
                    pending.popleft().result()
                    done += 1
                    if progress is not None:
                        progress(done, total)
            except BaseException:
                for future in pending:
                    future.cancel()
                raise
            # Before the recording is renamed into place: a sheet that fails takes the recording with it.
            sheet_path = None
            if config.contact_sheet is not None:
                sheet_path = write_contact_sheet(config.contact_sheet, sheet, force=force)
        loop_seconds = time.perf_counter() - loop_start

    return RecordResult(
        output=output,
        frames=total,
        keyframes=len(p.truth),
        seconds=time.perf_counter() - started,
        render_seconds=loop_seconds,
        contact_sheet=sheet_path,
    )


def _sheet_keyframes(n: int) -> list[int]:
    count = min(n, CONTACT_SHEET_FRAMES)
    return sorted({round(i * (n - 1) / max(1, count - 1)) for i in range(count)})


def write_contact_sheet(
    path: Path, frames: list[tuple[int, np.ndarray]], columns: int = 6, *, force: bool = False
) -> Path:
    """A grid of sample frames, each labelled with its keyframe index, as a PNG (``--force`` to replace)."""
    import cv2

    from aslam.data_formats.files import write_atomically

    if not frames:
        raise InputError("no frames for the contact sheet", path=path)
    h, w = frames[0][1].shape[:2]
    rows = -(-len(frames) // columns)
    sheet = np.full((rows * (h + 2), columns * (w + 2), 3), 24, np.uint8)
    scale = max(0.35, w / 640)
    for n, (index, rgb) in enumerate(frames):
        r, c = divmod(n, columns)
        tile = np.array(rgb, copy=True)
        label = f"#{index}"
        (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.rectangle(tile, (0, 0), (tw + 6, th + base + 6), (0, 0, 0), -1)
        cv2.putText(
            tile, label, (3, th + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA
        )
        sheet[r * (h + 2) : r * (h + 2) + h, c * (w + 2) : c * (w + 2) + w] = tile
    ok, buf = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if not ok:
        raise InputError("OpenCV could not encode the contact sheet", path=path)
    path = Path(path)
    data = buf.tobytes()
    write_atomically(path, lambda temporary: temporary.write_bytes(data), force=force)
    return path
