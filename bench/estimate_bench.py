"""Estimate wall time against its floor, measured in one run.

floor    = the same pipeline without SLAM: read the MCAP, keyframe test, decode keyframe images,
           compute histograms (``aslam.app.pipeline.run_floor``);
estimate = ``aslam estimate`` in-process (pipeline + SLAM + writing the estimate file + hashing).

Target: estimate ≤ 1.25 × floor. Runs alternate (floor, estimate, floor, ...) and the best of
each is kept, so page cache and CPU frequency treat both alike.

    python bench/estimate_bench.py [--recording R.mcap] [--laps 4] [--fps 3] [--repeats 3] [--json]

Without --recording it renders (once, cached in bench/.cache/) a paper-route recording.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from pathlib import Path

from aslam.app.estimate import estimate
from aslam.app.pipeline import run_floor
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator
from aslam.data_formats.recording import Recording
from aslam.recorder.config import RecordConfig
from aslam.recorder.record import record

CACHE = Path(__file__).resolve().parent / ".cache"


def recording_for(laps: int, fps: float) -> Path:
    path = CACHE / f"paper-laps{laps}-fps{fps:g}.mcap"
    if not path.exists():
        CACHE.mkdir(exist_ok=True)
        print(f"rendering {path.name} (once) ...", file=sys.stderr)
        record(RecordConfig(route="paper", laps=laps, fps=fps), path)
    return path


def time_floor(recording: Path, config: EstimatorConfig) -> tuple[float, int]:
    start = time.perf_counter()
    keyframes = run_floor(Recording(recording).samples(), Estimator(config))
    return time.perf_counter() - start, keyframes


def time_estimate(recording: Path, output: Path, config: EstimatorConfig) -> float:
    """The estimate's whole body (open, stream, SLAM, hash, write, rename), without the
    command-line parsing and interpreter start-up that the in-process floor does not pay either."""
    start = time.perf_counter()
    estimate(recording, output, config, force=True, timing=False)
    return time.perf_counter() - start


def time_parts(recording: Path, config: EstimatorConfig, repeats: int) -> dict[str, float]:
    """Where the difference goes, each part timed alone (best of ``repeats``), for the reader's sake:
    the SLAM steps on precomputed histograms, and the SHA-256 of the recording."""
    from contextlib import closing

    from aslam.app.pipeline import keyframe_histograms
    from aslam.core.estimator import keyframer as make_keyframer
    from aslam.core.observation import observation_model

    keyframer = make_keyframer(config)
    with closing(
        keyframe_histograms(
            Recording(recording).samples(), keyframer.action_if_keyframe, observation_model(config)
        )
    ) as stream:
        keyframes = list(stream)
    slam, sha = float("inf"), float("inf")
    for _ in range(repeats):
        estimator = Estimator(config)
        start = time.perf_counter()
        for k in keyframes:
            estimator.add_keyframe(k.stamp_ns, k.action, k.histogram)
        slam = min(slam, time.perf_counter() - start)
        start = time.perf_counter()
        digest = hashlib.sha256()
        with recording.open("rb") as f:
            while block := f.read(4 * 1024 * 1024):
                digest.update(block)
        sha = min(sha, time.perf_counter() - start)
    return {"slam_only_s": slam, "sha256_s": sha}


def main_bench() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--recording", type=Path)
    parser.add_argument("--laps", type=int, default=4)
    parser.add_argument("--fps", type=float, default=3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = parser.parse_args()
    recording = args.recording or recording_for(args.laps, args.fps)
    config = EstimatorConfig()
    floors, estimates = [], []
    keyframes = 0
    with tempfile.TemporaryDirectory() as folder:
        output = Path(folder) / "estimate.mcap"
        time_floor(recording, config)  # warm the page cache and imports
        for _ in range(args.repeats):
            floor, keyframes = time_floor(recording, config)
            floors.append(floor)
            estimates.append(time_estimate(recording, output, config))
    floor, estimate = min(floors), min(estimates)
    size_mb = recording.stat().st_size / 1e6
    if args.json:
        parts = time_parts(recording, config, args.repeats)
        result = {
            "recording": str(recording),
            "size_mb": size_mb,
            "keyframes": keyframes,
            "repeats": args.repeats,
            "floor_s": floor,
            "estimate_s": estimate,
            "ratio": estimate / floor,
            "keyframes_per_second": keyframes / estimate,
            **parts,
        }
        print(json.dumps(result))
        return
    print(f"recording   {recording} ({size_mb:.1f} MB, {keyframes} keyframes)")
    print(f"floor       {floor:.3f} s  (read + keyframe test + decode + histograms; best of {args.repeats})")
    print(f"estimate    {estimate:.3f} s  (the estimate command's body in-process; best of {args.repeats})")
    print(f"ratio       {estimate / floor:.3f}  (target ≤ 1.25)")
    print(f"keyframes/s {keyframes / estimate:.1f}")


if __name__ == "__main__":
    main_bench()
