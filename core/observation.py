"""Observation models: how an image becomes a vector, how two vectors differ, what that is worth.

At heart an observation model (:class:`ObservationModel`) does three things: describe a grey
image as a fixed-length float32 vector, measure the distance of one vector to many stored ones at
once (a matrix: the candidates of a step, or the whole map for relocalisation), and turn a
distance into a log-likelihood; the rest of the protocol is what the tree needs to calibrate the
new-place reference and index the views. Two implementations:

* :class:`HistogramModel` — the paper's gradient-orientation histogram compared with χ²
  (``aslam.core.features``), with the project's soft spatial cells;
* :class:`ThumbnailModel` — SeqSLAM's single-image comparison: a small patch-normalised
  thumbnail compared by mean absolute difference, minimised over small horizontal shifts so a
  revisit a few degrees off the first visit's heading still lines up.

Both map a distance ``d`` to ``log P(z|x) = -β log max(d, floor)``; the new-place reference is a
distance of the same kind (see :class:`aslam.core.tree.NewPlaceReference`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from aslam.core import portable_math
from aslam.core.config import EstimatorConfig, HistogramConfig


@runtime_checkable
class ObservationModel(Protocol):
    """What the hypothesis tree needs from an image descriptor."""

    @property
    def length(self) -> int:
        """Length of a place's view (:meth:`view`): what the map stores and the index keys."""
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
        """A float32 observation of a grey (H, W) or BGR (H, W, 3) image: its view (``length``
        values), which a place keeps, then whatever else a query is compared with."""
        ...

    def view(self, observation: np.ndarray) -> np.ndarray:
        """The part of an observation a place keeps: its first ``length`` values."""
        ...

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        """Distance (≥ 0, 0 for identical views) of ``observation`` (or a view alone) to each view
        in the rows of ``stored``."""
        ...

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        """``log P(z|x)`` of each distance (up to a constant shared by every candidate)."""
        ...

    @property
    def index_key_parts(self) -> tuple[int, ...]:
        """Lengths of the parts of every key ``index_key`` returns, one after the other."""
        ...

    def index_key(self, observation: np.ndarray) -> np.ndarray:
        """A float32 vector of parts, each of whose cosine similarity ranks stored views roughly as
        ``distances`` does: what the relocalisation index (:mod:`aslam.core.place_index`) searches,
        each part on its own."""
        ...

    def recognisable(self, observation: np.ndarray) -> bool:
        """Whether a view has the contrast to be told from others (a black frame has none): only
        such places are found by appearance alone."""
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

    def view(self, observation: np.ndarray) -> np.ndarray:
        return observation

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        from aslam.core.features import chi2_distances

        return chi2_distances(observation, stored)

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        return -self.beta * portable_math.log(np.maximum(distances, self.floor))

    @property
    def index_key_parts(self) -> tuple[int, ...]:
        return (min(self.length, INDEX_PROJECTION),)

    def index_key(self, observation: np.ndarray) -> np.ndarray:
        """The histogram, randomly projected when longer than ``INDEX_PROJECTION``."""
        return random_projection(self.length) @ np.asarray(observation, dtype=np.float32)

    def recognisable(self, observation: np.ndarray) -> bool:
        """Always: a histogram keeps no contrast (a blank view's is uniform, as a textured one's can be)."""
        return True


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
    phases: int = 4
    """Sub-column phases a query is described at (``thumbnail_phases``): the shifts above are whole
    columns, and a view a fraction of a column off differs in every column."""
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
        image = image.astype(np.float32, copy=False)
        w, h, phases = self.width_px, self.height_px, self.phases
        # The phases as channels of one small image, normalised together (each channel by itself:
        # the same arithmetic as one at a time, in a quarter of the calls).
        cells = np.empty((h, w, phases), np.float32)
        cells[:, :, 0] = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        if phases > 1:
            # Phase k: the image moved k/phases of a column to the left (its right edge repeated).
            fine = cv2.resize(image, (w * phases, h), interpolation=cv2.INTER_AREA)
            padded = np.concatenate([fine, np.repeat(fine[:, -1:], phases - 1, axis=1)], axis=1)
            # (C order, so the mean adds each cell's columns in the order one phase at a time did.)
            columns = np.ascontiguousarray(padded[:, _phase_columns(w, phases)])
            cells[:, :, 1:] = columns.mean(axis=3).transpose(0, 2, 1)
        return self._normalised(cells).reshape(h, w, phases).transpose(2, 0, 1).ravel()

    def _normalised(self, small: np.ndarray) -> np.ndarray:
        """Each cell by its ``patch_px`` neighbourhood's mean and spread (each channel on its own)."""
        import cv2

        small = small.astype(np.float64)
        size = (self.patch_px, self.patch_px)
        # (OpenCV returns one channel as a plain 2-D image.)
        mean = cv2.blur(small, size, borderType=cv2.BORDER_REFLECT).reshape(small.shape)
        mean_sq = cv2.blur(small * small, size, borderType=cv2.BORDER_REFLECT).reshape(small.shape)
        std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
        # A flat patch has no contrast to normalise: it stays 0 rather than amplifying noise.
        normalised = (small - mean) / np.maximum(std, 1.0)
        return normalised.astype(np.float32)

    def view(self, observation: np.ndarray) -> np.ndarray:
        return observation[: self.length]

    def distances(self, observation: np.ndarray, stored: np.ndarray) -> np.ndarray:
        """The least distance over the query's phases and the whole-column shifts."""
        stored = np.atleast_2d(stored)
        if stored.shape[0] == 0:
            return np.zeros(0)
        h, w, most = self.height_px, self.width_px, self.max_shift_px
        queries = np.asarray(observation, dtype=np.float32).reshape(-1, h, w)
        rows = stored.reshape(-1, h, w)
        totals = np.empty((2 * most + 1, len(rows), len(queries)))
        for k, shift in enumerate(range(-most, most + 1)):
            if shift >= 0:
                a, b = queries[:, :, shift:], rows[:, :, : w - shift]
            else:
                a, b = queries[:, :, :shift], rows[:, :, -shift:]
            differences = b[:, None] - a[None]
            np.abs(differences, out=differences)
            # np.mean's own arithmetic (a float64 sum, then one division) without its Python overhead.
            np.add.reduce(differences, axis=(2, 3), dtype=np.float64, out=totals[k])
        return (totals.min(axis=2) / _overlaps(h, w, most)[:, None]).min(axis=0)

    def log_likelihood(self, distances: np.ndarray | float) -> np.ndarray:
        return -self.beta * portable_math.log(np.maximum(distances, self.floor))

    @property
    def index_key_parts(self) -> tuple[int, ...]:
        return (self.height_px * INDEX_FREQUENCIES, min(self.length, INDEX_PROJECTION))

    def index_key(self, observation: np.ndarray) -> np.ndarray:
        """Two parts, each searched on its own: the magnitudes of each row's lowest horizontal
        frequencies, blind to a sideways shift of the view as the comparison over shifts is, and
        the thumbnail randomly projected, which keeps where things are.

        Measured (12 places shortlisted per part; the share of revisits with a true place in the
        shortlist): on eight matrix renders (497 revisits), where a revisit a few degrees off the
        first visit's heading sees the scene shifted sideways, the projection alone shortlisted 0.78
        and the frequencies alone 0.97; on Nordland summer → winter (1,788 frames, a camera fixed to
        the train) 0.19 and 0.12.
        """
        view = np.asarray(observation, dtype=np.float32)
        parts = view.reshape(self.height_px, self.width_px) @ _row_frequencies(self.width_px)
        blind = np.hypot(parts[:, :INDEX_FREQUENCIES], parts[:, INDEX_FREQUENCIES:]).ravel()
        return np.concatenate([blind, random_projection(self.length) @ view])

    def recognisable(self, observation: np.ndarray) -> bool:
        """Some patches had contrast: a textured view's values average about 0.6 in magnitude (0.35
        at the least in the matrix renders, 0.25 in a Nordland tunnel), a black frame's 0.05–0.1 (the
        17 black frames that open Nordland's summer journey, where a winter tunnel found its way in)."""
        return float(np.mean(np.abs(observation))) >= BLANK_CONTRAST


BLANK_CONTRAST = 0.2
"""Mean magnitude of a thumbnail below which the view is blank: a quarter of a textured view's (whose
patch-normalised values have unit spread, about 0.8 in mean magnitude). A black frame's sensor
noise, averaged into the thumbnail's cells, stays under the 1-grey-level floor of the
normalisation: 0.05 for Nordland's black frames, 0.10 for a 320 × 240 camera with its lens capped."""
INDEX_FREQUENCIES = 3
"""Horizontal frequencies per thumbnail row in its index key (0, 1 and 2 cycles per width)."""
INDEX_PROJECTION = 32
"""Dimensions a longer vector is randomly projected to for the index."""


@functools.cache
def _overlaps(height: int, width: int, most: int) -> np.ndarray:
    """Cells two thumbnails share at each shift from ``-most`` to ``most`` columns."""
    overlaps = height * (width - np.abs(np.arange(-most, most + 1)))
    overlaps.flags.writeable = False  # shared by every comparison
    return overlaps


@functools.cache
def _phase_columns(width: int, phases: int) -> np.ndarray:
    """``(phases − 1, width, phases)`` columns of the padded fine image: for phase k, cell c averages
    fine columns ``c·phases + k`` to ``c·phases + k + phases − 1``."""
    k = np.arange(1, phases)[:, None, None]
    columns = k + (np.arange(width) * phases)[None, :, None] + np.arange(phases)[None, None, :]
    columns.flags.writeable = False  # shared by every description
    return columns


@functools.cache
def _row_frequencies(width: int) -> np.ndarray:
    """(width, 2 × INDEX_FREQUENCIES): a row times this is the real, then the imaginary parts of its
    discrete Fourier transform at 0, 1, 2 … cycles per width (one product, not an FFT per row)."""
    angles = 2.0 * np.pi * np.outer(np.arange(width), np.arange(INDEX_FREQUENCIES)) / width
    basis = np.concatenate([np.cos(angles), -np.sin(angles)], axis=1).astype(np.float32)
    basis.flags.writeable = False
    return basis


@functools.cache
def random_projection(length: int) -> np.ndarray:
    """A fixed random projection (Johnson–Lindenstrauss) to ``INDEX_PROJECTION`` dimensions, or the
    identity. Angles between vectors are nearly kept.

    Made on first use (``numpy.random``'s import is 10 ms of an estimate's start-up), once per length.
    """
    if length <= INDEX_PROJECTION:
        identity = np.eye(length, dtype=np.float32)
        identity.flags.writeable = False
        return identity
    rng = np.random.default_rng(20261129)
    projection = (rng.standard_normal((INDEX_PROJECTION, length)) / math.sqrt(INDEX_PROJECTION)).astype(
        np.float32
    )
    projection.flags.writeable = False  # shared by every index of that length
    return projection


@dataclass(frozen=True)
class ObservationModelChoice:
    """One value of ``EstimatorConfig.observation_model``: its model, made from a configuration, and
    the parameters that change the vectors ``describe`` makes (the others only weigh distances)."""

    make: Callable[[EstimatorConfig], ObservationModel]
    descriptor_parameters: tuple[str, ...] = ()


OBSERVATION_MODELS: dict[str, ObservationModelChoice] = {
    "histogram": ObservationModelChoice(
        lambda config: HistogramModel(
            config.histogram, config.beta, config.chi2_floor, config.new_state_chi2
        ),
        ("histogram_bins", "cells_x", "cells_y"),
    ),
    "thumbnail": ObservationModelChoice(
        lambda config: ThumbnailModel(beta=config.thumbnail_beta, phases=config.thumbnail_phases)
    ),
}
"""Every observation model by its name: the one place a model is registered (the names
``EstimatorConfig`` accepts, the model it makes, what a prior map's views must share)."""


def descriptor_key(config: EstimatorConfig) -> str:
    """What decides the vector ``describe`` makes under ``config``, as the ``aslam estimate`` options
    that set it: views stored by one run can be compared by another only when these are equal (a
    prior map, ``estimate --map``)."""
    name = config.observation_model
    options = [
        f"--{parameter.replace('_', '-')} {getattr(config, parameter)}"
        for parameter in OBSERVATION_MODELS[name].descriptor_parameters
    ]
    return " ".join([f"--observation-model {name}", *options])


def observation_model(config: EstimatorConfig) -> ObservationModel:
    """The model ``config.observation_model`` names, with the configuration's parameters."""
    return OBSERVATION_MODELS[config.observation_model].make(config)
