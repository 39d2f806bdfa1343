"""`aslam estimate` against an independent floor, whole processes, measured in one run.

floor    = ``bench/floor.py``: one process that shares no code with aslam (mcap reader, imdecode,
           Sobel, a 32-bin orientation histogram per image, nothing else);
estimate = the ``aslam estimate REC -o OUT --no-timing --quiet`` process, start-up included.

Runs alternate (floor, estimate, floor, …) so page cache, CPU frequency and other load treat both
alike; the ratio of medians is reported with the spread of the per-pair ratios. A per-stage
breakdown of the estimate (in-process, each stage alone) says where the time goes, and the
start-up costs are measured as processes too (`aslam --help`; `estimate` on a one-image recording;
a process importing the floor's libraries, and one importing the estimate's).

    python bench/estimate_bench.py [--recording R.mcap] [--route grid] [--size 320x240] [--repeats 5]
    python bench/estimate_bench.py --laps 8 --config bench/configs/geometric-check.toml   # a setting's cost

Without --recording it renders (once, cached in bench/.cache/) a recording with one image per
keyframe, so the floor decodes exactly the images the estimate decodes.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import closing
from pathlib import Path

import numpy as np
from measure import spread

from aslam.app.config_file import build_config
from aslam.app.estimate import geometry_camera
from aslam.app.metric_view import embed_run, metric_scene, preload
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator, keyframer
from aslam.core.geometry import ViewFeatures, view_features
from aslam.core.observation import observation_model
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.estimate import EstimateWriter
from aslam.data_formats.files import source_sha256
from aslam.data_formats.foxglove import write_scene
from aslam.data_formats.images import encode_image
from aslam.data_formats.recording import Recording
from aslam.data_formats.recording_writer import RecordingWriter
from aslam.data_formats.sources import open_input
from aslam.recorder.config import CameraSpec, RecordConfig, parse_size
from aslam.recorder.record import record

#: What the libraries alone cost, each set imported by a fresh process that does nothing else: the
#: floor's own imports (bench/floor.py), and those with every other library an ``aslam estimate``
#: process and its reader load (typer, imagecodecs, mcap's writer, mcap-protobuf, GTSAM for the
#: metric view, Foxglove's schemas). On a short recording the second takes about as long as the
#: floor's whole run: the bound the estimate's start-up cannot go under.
FLOOR_LIBRARIES = "import cv2, numpy, mcap.reader, mcap_ros2.decoder"
ESTIMATE_LIBRARIES = (
    FLOOR_LIBRARIES + ", typer, imagecodecs, mcap.writer, mcap_protobuf.schema, gtsam,"
    " foxglove_schemas_protobuf.FrameTransform_pb2, foxglove_schemas_protobuf.LinePrimitive_pb2,"
    " foxglove_schemas_protobuf.PosesInFrame_pb2, foxglove_schemas_protobuf.SceneUpdate_pb2"
)

BENCH = Path(__file__).resolve().parent
CACHE = BENCH / ".cache"
ASLAM = Path(sys.executable).with_name("aslam")


def recording_for(route: str, size: str, laps: int | None) -> Path:
    path = CACHE / f"{route}-{size}-laps{laps or 'default'}.mcap"
    if not path.exists():
        CACHE.mkdir(exist_ok=True)
        print(f"rendering {path.name} (once) ...", file=sys.stderr)
        width, height = parse_size(size)
        record(
            RecordConfig(route=route, laps=laps, camera=CameraSpec(width_px=width, height_px=height)), path
        )
    return path


def wall(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - start


def third_party_imports(command: list[str]) -> set[str]:
    """The top-level packages outside the standard library that ``command`` imports, its forked
    reader's included (``-X importtime`` is inherited), aslam's own left out."""
    env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1", "ASLAM_DEBUG": "1"}  # (debug: stderr kept)
    run = subprocess.run(
        command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=True
    )
    names = {
        line.rsplit("|", 1)[1].strip().split(".")[0]
        for line in run.stderr.splitlines()
        if line.startswith("import time:") and line.count("|") == 2
    }
    return {name for name in names if name not in sys.stdlib_module_names and name not in ("aslam", "")}


def stages(recording: Path, config: EstimatorConfig, output: Path) -> dict[str, float]:
    """Seconds of each stage alone, in-process, one thread: where the estimate's time goes."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    keyframe_test = keyframer(config)
    keyframes = []
    with closing(Recording(recording).samples()) as samples:
        for sample, action in keyframe_test.keyframes(samples, lambda sample: sample.odometry_pose):
            keyframes.append((sample.stamp_ns, action, sample.image))
    timings["read_and_sync_s"] = time.perf_counter() - start
    start = time.perf_counter()
    grays = [image.decode_gray() for _, _, image in keyframes]
    timings["decode_s"] = time.perf_counter() - start
    start = time.perf_counter()
    model = observation_model(config)
    observations = [model.describe(gray) for gray in grays]
    timings["describe_s"] = time.perf_counter() - start
    camera = None
    features: list[ViewFeatures | None] = [None] * len(grays)
    if config.geometric_check_m > 0:  # the geometric check's features, and its camera
        camera = geometry_camera(open_input(recording), recording)
        start = time.perf_counter()
        features = [view_features(gray) for gray in grays]
        timings["features_s"] = time.perf_counter() - start
    estimator = Estimator(config, camera=camera)
    start = time.perf_counter()
    steps = [
        estimator.add_keyframe(stamp, action, observation, features=view)
        for (stamp, action, _), observation, view in zip(keyframes, observations, features, strict=True)
    ]
    result = estimator.result()
    timings["slam_s"] = time.perf_counter() - start
    start = time.perf_counter()
    preload()  # GTSAM and Foxglove's schemas, first imported here as in a fresh `aslam estimate`
    timings["metric_view_imports_s"] = time.perf_counter() - start
    start = time.perf_counter()
    actions = np.array([action for _, action, _ in keyframes]).reshape(-1, 3)
    embedding = embed_run(actions, result.states, result.links, config, result.first_keyframe)
    scene = None if embedding is None else metric_scene(embedding, result.keyframe_stamps_ns)
    timings["metric_view_s"] = time.perf_counter() - start
    start = time.perf_counter()
    with EstimateWriter(output, tool_version="bench", force=True) as writer:
        for step in steps:
            writer.write_keyframe(step)
        writer.abort()
    if scene is not None:  # the metric view, as the estimate file's last writes hold it
        write_scene(output.with_name("scene.mcap"), scene, force=True)
    timings["write_s"] = time.perf_counter() - start
    del result
    start = time.perf_counter()
    source_sha256(recording)  # what estimate() hashes, on its thread, while it runs
    timings["sha256_s"] = time.perf_counter() - start
    timings["keyframes"] = len(keyframes)
    return timings


def one_image_recording(folder: Path) -> Path:
    path = folder / "one.mcap"
    pixels = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    with RecordingWriter(path, camera=CameraIntrinsics(320, 240, 60.0), metadata={}) as writer:
        writer.write(1, encode_image(pixels), np.zeros(3), None)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--recording", type=Path)
    parser.add_argument("--route", default="grid")
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--laps", type=int)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true", help="one line of JSON (for bench/speed.py)")
    parser.add_argument(
        "--config",
        type=Path,
        help="an estimator config file (TOML, as `aslam estimate --config`) for the estimate and the stages",
    )
    args = parser.parse_args()
    config = build_config(paper_faithful=False, config_file=args.config, options={})
    recording = args.recording or recording_for(args.route, args.size, args.laps)
    # What a (non-editable) install does: the processes below then load bytecode, as a user's do,
    # even where PYTHONDONTWRITEBYTECODE is set (as in many CI images).
    packages = [str(BENCH.parent / name) for name in ("app", "cli", "core", "data_formats", "recorder")]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *packages], check=True)
    floors, estimates, ratios, helps, startups = [], [], [], [], []
    floor_libraries, estimate_libraries = [], []
    with tempfile.TemporaryDirectory() as folder:
        output = Path(folder) / "estimate.mcap"
        one = one_image_recording(Path(folder))
        floor_cmd = [sys.executable, str(BENCH / "floor.py"), str(recording)]
        estimate_cmd = [
            str(ASLAM),
            "estimate",
            str(recording),
            "-o",
            str(output),
            "--force",
            "--no-timing",
            "-q",
            *(["--config", str(args.config)] if args.config is not None else []),
        ]
        startup_cmd = [str(ASLAM), "estimate", str(one), "-o", str(output), "--force", "--no-timing", "-q"]
        wall(floor_cmd), wall(estimate_cmd)  # warm the page cache and the interpreter's files
        for _ in range(args.repeats):
            floors.append(wall(floor_cmd))
            estimates.append(wall(estimate_cmd))
            ratios.append(estimates[-1] / floors[-1])
            helps.append(wall([str(ASLAM), "--help"]))
            startups.append(wall(startup_cmd))
            floor_libraries.append(wall([sys.executable, "-c", FLOOR_LIBRARIES]))
            estimate_libraries.append(wall([sys.executable, "-c", ESTIMATE_LIBRARIES]))
        # ESTIMATE_LIBRARIES must stay every library an estimate loads, or its figure is low.
        listed = third_party_imports([sys.executable, "-c", ESTIMATE_LIBRARIES])
        missing = third_party_imports(estimate_cmd) - listed
        if missing:
            print(f"warning: the estimate imports {sorted(missing)}, not listed", file=sys.stderr)
        parts = stages(recording, config, output)
    result = {
        "recording": str(recording),
        "size_mb": recording.stat().st_size / 1e6,
        "repeats": args.repeats,
        "floor_s": spread(floors),
        "estimate_s": spread(estimates),
        "ratio_of_medians": statistics.median(estimates) / statistics.median(floors),
        "pair_ratio": spread(ratios),
        "help_s": spread(helps),
        "estimate_startup_s": spread(startups),
        "help_samples_s": helps,
        "estimate_startup_samples_s": startups,
        "floor_libraries_s": spread(floor_libraries),
        "estimate_libraries_s": spread(estimate_libraries),
        "libraries_not_listed": sorted(missing),
        "stages": parts,
        "keyframes_per_second": parts["keyframes"] / statistics.median(estimates),
    }
    print(json.dumps(result) if args.json else json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
