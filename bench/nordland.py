"""Nordland summer → winter: SeqSLAM against aslam, in one run, on real frames.

The map is the summer journey, the queries the winter one; ``summer/images-N`` and
``winter/images-N`` show the same place, and a match within ±1 file is correct (the dataset's
usual tolerance). For each method: best-match accuracy, and over a confidence threshold the
precision-recall curve, its area (AUC, average precision) and the recall at 100 % precision.
aslam runs twice: its observation models on single images, and the whole tool — summer estimated
as a map, winter localised in it with ``estimate --map`` (the hypothesis tree as the sequence
matcher). A control then runs the journey's second half in a map of its first half: every claim
into the map is wrong there.

    python bench/nordland.py [--data ../shared/data/nordland-64x32] [--first 10] [--last 17880]

Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from seqslam import SeqSlamParams, difference_matrix, enhance_contrast, patch_normalise, sequence_search

from aslam.core.config import HistogramConfig
from aslam.core.observation import HistogramModel, ObservationModel, ThumbnailModel

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "nordland-64x32"
TOLERANCE = 1
LONGEST_SEQUENCE = 20
"""SeqSLAM's longer sequence length here; a part of fewer files has no line that fits in it."""
MAP_REFERENCE_SCALE = 0.95
"""``--map-reference-scale`` of the winter run: summer → winter is a change of season (docs/real-data.md)."""


def frames(folder: Path, first: int, last: int) -> tuple[list[int], np.ndarray]:
    numbers = sorted(int(p.stem.split("-")[1]) for p in folder.glob("images-*.png"))
    numbers = [n for n in numbers if first <= n <= last]
    images = np.stack(
        [cv2.imread(str(folder / f"images-{n:05d}.png"), cv2.IMREAD_GRAYSCALE) for n in numbers]
    )
    return numbers, images


def place_recognition_scores(match: np.ndarray, confidence: np.ndarray) -> dict[str, float]:
    """Query j's true reference is j (aligned lists); ``confidence``: higher is surer."""
    correct = np.abs(match - np.arange(len(match))) <= TOLERANCE
    order = np.argsort(-confidence, kind="stable")
    hits = np.cumsum(correct[order])
    claimed = np.arange(1, len(order) + 1)
    precision = hits / claimed
    recall = hits / len(match)
    perfect = np.flatnonzero(precision >= 1.0)
    average_precision = float(np.sum(precision * correct[order]) / len(match))
    return {
        "best_match_accuracy": float(correct.mean()),
        "recall_at_full_precision": float(recall[perfect[-1]]) if perfect.size else 0.0,
        "auc": average_precision,
    }


def seqslam(references: np.ndarray, queries: np.ndarray, length: int) -> dict[str, float]:
    params = SeqSlamParams(sequence_length=length)
    start = time.perf_counter()
    d = difference_matrix(
        patch_normalise(references, params.patch_px), patch_normalise(queries, params.patch_px)
    )
    match, confidence = sequence_search(enhance_contrast(d, params.contrast_window), params)
    scores = place_recognition_scores(match, confidence)
    return {**scores, "seconds": time.perf_counter() - start}


def single_image(references: np.ndarray, queries: np.ndarray, model: ObservationModel) -> dict[str, float]:
    """One of aslam's observation models, best match per image alone (no sequence, no odometry)."""
    start = time.perf_counter()
    stored = np.stack([model.view(model.describe(image)) for image in references])
    match = np.empty(len(queries), int)
    confidence = np.empty(len(queries))
    for j, image in enumerate(queries):
        distances = model.distances(model.describe(image), stored)
        best = int(np.argmin(distances))
        outside = np.concatenate([distances[: max(best - 10, 0)], distances[best + 11 :]])
        match[j] = best
        confidence[j] = float(outside.min() - distances[best]) if outside.size else 0.0
    return {**place_recognition_scores(match, confidence), "seconds": time.perf_counter() - start}


def _recording(data: Path, season: str, numbers: list[int], workdir: Path, name: str) -> Path:
    """``numbers``' frames of ``season`` imported as a user would (``aslam import``: no odometry)."""
    from aslam.app.importer import import_image_folder

    folder = workdir / name
    folder.mkdir()
    for n in numbers:
        (folder / f"images-{n:05d}.png").symlink_to((data / season / f"images-{n:05d}.png").absolute())
    recording = workdir / f"{name}.mcap"
    import_image_folder(folder, recording, rate_hz=2.5)
    return recording


def _estimate(recording: Path, output: Path, prior: Path | None = None, scale: float = 0.0) -> Path:
    from aslam.app.estimate import estimate
    from aslam.core.config import EstimatorConfig

    estimate(recording, output, EstimatorConfig(map_reference_scale=scale), timing=False, prior=prior)
    return output


def aslam_map(data: Path, numbers: list[int], workdir: Path) -> dict[str, float]:
    """aslam itself, as a user runs it: each season imported (no odometry: equal steps), the summer
    estimate as the map, winter estimated in it (``--map``, ``--map-reference-scale 0.95``), scored
    with ``--truth-by-index``.

    The best hypothesis's claim at each winter keyframe is its match; its belief, the confidence.
    ``committed`` scores the map the hypotheses agreed on (each keyframe's final place).
    """
    from aslam.app.score import score

    start = time.perf_counter()
    summer_map = _estimate(
        _recording(data, "summer", numbers, workdir, "summer"), workdir / "summer.est.mcap"
    )
    winter = _estimate(
        _recording(data, "winter", numbers, workdir, "winter"),
        workdir / "winter.est.mcap",
        prior=summer_map,
        scale=MAP_REFERENCE_SCALE,
    )
    summary = score(winter, truth_by_index=True, radius_m=float(TOLERANCE)).summary
    closure = summary["loop_closure"]
    return {
        "best_match_accuracy": closure["recall"],
        "recall_at_full_precision": closure["recall_at_full_precision"],
        "auc": closure["auc"],
        "precision": closure["precision"],
        "committed_accuracy": summary["committed"]["recall"],
        "seconds": time.perf_counter() - start,
    }


def new_ground(data: Path, numbers: list[int], workdir: Path) -> dict[str, dict[str, int]]:
    """The control: a map of the journey's first half, runs over its second half (no frame of it in
    the map), with and without ``--map-reference-scale``: every claim into the map is wrong."""
    from contextlib import closing

    from aslam.data_formats.estimate import iter_keyframes

    half = len(numbers) // 2
    the_map = _estimate(_recording(data, "summer", numbers[:half], workdir, "map"), workdir / "map.est.mcap")
    out: dict[str, dict[str, int]] = {}
    for season in ("winter", "summer"):
        recording = _recording(data, season, numbers[half:], workdir, f"{season}-new")
        for scale in (0.0, MAP_REFERENCE_SCALE):
            estimate_file = _estimate(recording, workdir / f"{season}-{scale}.est.mcap", the_map, scale)
            with closing(iter_keyframes(estimate_file)) as keyframes:
                claims = sum(
                    1 for k in keyframes if not k.hypotheses[0].is_new_state and k.hypotheses[0].state < half
                )
            out[f"{season}, map_reference_scale {scale:g}"] = {
                "frames": len(numbers) - half,
                "claims_into_map": claims,
            }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--first", type=int, default=10)
    parser.add_argument("--last", type=int, default=17880)
    args = parser.parse_args()
    if not all((args.data / season).is_dir() for season in ("summer", "winter")):
        parser.error(f"{args.data}: no summer/ and winter/ folders of Nordland frames here; give --data DIR")
    summer_numbers, summer = frames(args.data / "summer", args.first, args.last)
    winter_numbers, winter = frames(args.data / "winter", args.first, args.last)
    if summer_numbers != winter_numbers:
        raise SystemExit("summer and winter frame numbers differ")
    if len(summer_numbers) < LONGEST_SEQUENCE:  # every SeqSLAM line would leave the part: no score
        parser.error(
            f"frames {args.first}-{args.last} hold {len(summer_numbers)} files; SeqSLAM needs at least"
            f" {LONGEST_SEQUENCE} (its sequence length)"
        )
    result = {
        "frames": len(summer_numbers),
        "range": [summer_numbers[0], summer_numbers[-1]],
        "tolerance_files": TOLERANCE,
        "seqslam_length_10": seqslam(summer, winter, 10),
        "seqslam_length_20": seqslam(summer, winter, LONGEST_SEQUENCE),
        "aslam_histogram_paper": single_image(summer, winter, HistogramModel(HistogramConfig(16, 1, 1))),
        "aslam_histogram_cells": single_image(summer, winter, HistogramModel(HistogramConfig(16, 2, 1))),
        "aslam_thumbnail": single_image(summer, winter, ThumbnailModel()),
    }
    with tempfile.TemporaryDirectory(prefix="aslam-nordland-") as workdir:
        result["aslam_map"] = aslam_map(args.data, summer_numbers, Path(workdir))
    with tempfile.TemporaryDirectory(prefix="aslam-nordland-") as workdir:
        result["aslam_new_ground"] = new_ground(args.data, summer_numbers, Path(workdir))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
