"""Which observation model finds the right place: distances of each keyframe to every earlier one.

For every keyframe with a true revisit (an earlier keyframe within 0.5 m and 45°) it counts
whether the nearest earlier view by the model is such a revisit, and prints distance percentiles
for the same place, places 0.7–1.5 m away and the rest, plus the median distance between
consecutive keyframes (what the online new-place reference is made from).

    python bench/observation_calibration.py /tmp/robust/rec/jitter15-paper-seed1.mcap ...
"""

from __future__ import annotations

import argparse
from contextlib import closing
from pathlib import Path

import numpy as np

MODELS = {
    "histogram": lambda: _histogram(),
    "thumb32x24": lambda: _thumbnail(32, 24, 5, 0),
    "thumb32x24s3": lambda: _thumbnail(32, 24, 5, 3),
    "thumb16x12s4": lambda: _thumbnail(16, 12, 5, 4),
}


def _histogram():
    from aslam.core.config import EstimatorConfig
    from aslam.core.observation import HistogramModel

    return HistogramModel(EstimatorConfig().histogram)


def _thumbnail(width: int, height: int, patch: int, shift: int):
    from aslam.core.observation import ThumbnailModel

    return ThumbnailModel(width_px=width, height_px=height, patch_px=patch, max_shift_px=shift)


def keyframes(path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """(grey image, true pose) of each keyframe, chosen by the default keyframe test."""
    from aslam.core.config import EstimatorConfig
    from aslam.core.estimator import keyframer
    from aslam.data_formats.recording import Recording

    test = keyframer(EstimatorConfig())
    out = []
    with closing(Recording(path).samples()) as samples:
        for sample, _ in test.keyframes(samples, lambda sample: sample.odometry_pose):
            out.append((sample.image.decode_gray(), np.asarray(sample.ground_truth_pose, float)))
    return out


def calibrate(path: Path, names: list[str]) -> None:
    from aslam.core import se2
    from aslam.core.config import REVISIT_HEADING_DEG, REVISIT_RADIUS_M

    frames = keyframes(path)
    truth = np.array([pose for _, pose in frames])
    print(f"{path.name}: {len(frames)} keyframes")
    for name in names:
        model = MODELS[name]()
        z = np.array([model.describe(image) for image, _ in frames])
        same, near, other, right, revisits = [], [], [], 0, 0
        for t in range(1, len(frames)):
            d = model.distances(z[t], np.array([model.view(v) for v in z[:t]]))
            metres = np.hypot(*(truth[:t, :2] - truth[t, :2]).T)
            degrees = np.degrees(np.abs(se2.wrap_angle(truth[:t, 2] - truth[t, 2])))
            true = (metres <= REVISIT_RADIUS_M) & (degrees <= REVISIT_HEADING_DEG)  # the scoring's tolerance
            if true.any():
                revisits += 1
                same.append(d[true].min())
                right += bool(true[np.argmin(d)])
            close = (metres > 0.7) & (metres < 1.5) & (degrees <= 45)
            if close.any():
                near.append(d[close].min())
            far = ~((metres <= 1.5) & (degrees <= 45))
            if far.any():
                other.append(d[far].min())
        consecutive = [model.distances(z[t], model.view(z[t - 1]))[0] for t in range(1, len(z))]

        def pct(values: list[float], q: float) -> float:
            return float(np.percentile(values, q)) if values else float("nan")

        print(
            f"  {name:14s} nearest is a true revisit {right}/{revisits}; same place median/p90"
            f" {pct(same, 50):.4f}/{pct(same, 90):.4f}; 0.7–1.5 m p10/median {pct(near, 10):.4f}/"
            f"{pct(near, 50):.4f}; other p10 {pct(other, 10):.4f}; consecutive median"
            f" {float(np.median(consecutive)):.4f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", nargs="+", type=Path)
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    args = parser.parse_args()
    for path in args.recordings:
        calibrate(path, args.models)


if __name__ == "__main__":
    main()
