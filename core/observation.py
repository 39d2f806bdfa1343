"""Observation models: how an image becomes a vector, how two vectors differ, what that is worth.

The tree only needs three things from an observation model (:class:`ObservationModel`): describe
a grey image as a fixed-length float32 vector, measure the distance of one vector to many stored
ones at once (a matrix: the candidates of a step, or the whole map for relocalisation), and turn
a distance into a log-likelihood. Two implementations:

* :class:`HistogramModel` — the paper's gradient-orientation histogram compared with χ²
  (``aslam.core.features``), with the project's soft spatial cells;
* :class:`ThumbnailModel` — SeqSLAM's single-image comparison: a small patch-normalised
  thumbnail compared by mean absolute difference, minimised over small horizontal shifts so a
  revisit a few degrees off the first visit's heading still lines up.

Both map a distance ``d`` to ``log P(z|x) = -β log max(d, floor)``; the new-place reference is a
distance of the same kind (see :class:`aslam.core.tree.NewPlaceReference`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from aslam.core.config import EstimatorConfig, HistogramConfig


@runtime_checkable
class ObservationModel(Protocol):
    """What the hypothesis tree needs from an image descriptor."""

    @property
    def length(self) -> int:
        """Length of every vector ``describe`` returns."""
        ...

    @property
    def fixed_reference(self) -> float:
        """Distance of an unseen place when the reference is not calibrated online."""
        ...

    @property
    def floor(self) -> float:
        """Distances below this all count as this (likelihoods stay finite; identical views)."""
        ...

    @property
    def online_scale(self) -> float:
        """Online reference = this × the running median distance between consecutive keyframes."""
        ...

    def describe(self, gray: np.ndarray) -> np.ndarray:
        """A float32 vector of ``length`` for a grey (H, W) or BGR (H, W, 3) image."""
        ...

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        """Distance (≥ 0, 0 for identical views) of ``observation`` to each row of ``stored``."""
        ...

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        """``log P(z|x)`` of each distance (up to a constant shared by every candidate)."""
        ...


@dataclass(frozen=True)
class HistogramModel:
    """The paper's observation: gradient-orientation histograms (soft cells) and χ², ``P = χ²^-β``."""

    histogram: HistogramConfig = field(default_factory=HistogramConfig)
    beta: float = 3.0
    floor: float = 1e-3
    fixed_reference: float = 0.08
    """χ² of an unseen place (calibrated on our renders, docs/estimator.md)."""
    online_scale: float = 2.2
    """Online reference: this × the median χ² between consecutive keyframes (0.03–0.04 on our renders)."""

    @property
    def length(self) -> int:
        return self.histogram.length

    def describe(self, gray: np.ndarray) -> np.ndarray:
        from aslam.core.features import orientation_histogram

        return orientation_histogram(gray, self.histogram)

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        from aslam.core.features import chi2_distances

        return chi2_distances(observation, stored)

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        return -self.beta * np.log(np.maximum(distances, self.floor))


@dataclass(frozen=True)
class ThumbnailModel:
    """A patch-normalised thumbnail (SeqSLAM, Milford & Wyeth 2012) compared by mean absolute difference.

    The image is shrunk to ``width_px`` × ``height_px`` (area averaging: the blur removes texture
    aliasing), then each pixel is normalised by the mean and standard deviation of the
    ``patch_px`` neighbourhood around it, so only local contrast remains: a change of lighting
    or exposure does not move it. Two thumbnails are compared at horizontal shifts of up to
    ``max_shift_px`` (the best shift wins), because a revisit a few degrees off the first visit's
    heading sees the same scene displaced sideways; only the overlapping columns count.
    """

    width_px: int = 16
    height_px: int = 12
    patch_px: int = 5
    max_shift_px: int = 4
    """±4 of 16 columns: ±15° of a 60° field of view."""
    beta: float = 8.0
    floor: float = 0.02
    fixed_reference: float = 0.56
    online_scale: float = 0.8
    """Online reference: this × the median distance between consecutive keyframes (≈0.74 on our renders)."""

    @property
    def length(self) -> int:
        return self.width_px * self.height_px

    def describe(self, gray: np.ndarray) -> np.ndarray:
        import cv2

        image = np.asarray(gray)
        if image.ndim == 3:
            image = cv2.cvtColor(image.astype(np.float32, copy=False), cv2.COLOR_BGR2GRAY)
        small = cv2.resize(
            image.astype(np.float32, copy=False),
            (self.width_px, self.height_px),
            interpolation=cv2.INTER_AREA,
        ).astype(np.float64)
        size = (self.patch_px, self.patch_px)
        mean = cv2.blur(small, size, borderType=cv2.BORDER_REFLECT)
        mean_sq = cv2.blur(small * small, size, borderType=cv2.BORDER_REFLECT)
        std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
        # A flat patch has no contrast to normalise: it stays 0 rather than amplifying noise.
        normalised = (small - mean) / np.maximum(std, 1.0)
        return normalised.astype(np.float32).ravel()

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        stored = np.atleast_2d(stored)
        if stored.shape[0] == 0:
            return np.zeros(0)
        h, w = self.height_px, self.width_px
        query = np.asarray(observation, dtype=np.float32).reshape(h, w)
        rows = stored.reshape(-1, h, w)
        best = np.full(len(rows), np.inf)
        for shift in range(-self.max_shift_px, self.max_shift_px + 1):
            if shift >= 0:
                a, b = query[:, shift:], rows[:, :, : w - shift]
            else:
                a, b = query[:, :shift], rows[:, :, -shift:]
            # np.mean's own arithmetic (a float64 sum, then one division) without its Python overhead.
            total = np.add.reduce(np.abs(b - a), axis=(1, 2), dtype=np.float64)
            best = np.minimum(best, total / (h * a.shape[1]))
        return best

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        return -self.beta * np.log(np.maximum(distances, self.floor))


OBSERVATION_MODELS = ("histogram", "thumbnail")


def descriptor_key(config: EstimatorConfig) -> str:
    """What decides the vector ``describe`` makes under ``config``, as the ``aslam estimate`` options
    that set it: views stored by one run can be compared by another only when these are equal (a
    prior map, ``estimate --map``)."""
    if config.observation_model == "thumbnail":
        return "--observation-model thumbnail"
    h = config.histogram
    cells = f"--cells-x {h.cells_x} --cells-y {h.cells_y}"
    return f"--observation-model histogram --histogram-bins {h.bins} {cells}"


def observation_model(config: EstimatorConfig) -> ObservationModel:
    """The model ``config.observation_model`` names, with the configuration's parameters."""
    if config.observation_model == "thumbnail":
        return ThumbnailModel(beta=config.thumbnail_beta)
    return HistogramModel(config.histogram, config.beta, config.chi2_floor, config.new_state_chi2)
