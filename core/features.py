"""Observations: gradient-orientation histograms compared with χ² (the paper's section V-B).

A histogram counts how much edge there is in each direction, weighted by gradient magnitude, so
it is cheap, needs no landmarks and does not change when the lighting is scaled uniformly.
Optional spatial cells (a grid of image strips, each with its own histogram, concatenated) keep
some of *where* the edges are, which separates places the single global histogram confuses.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from aslam.core.config import HistogramConfig


def orientation_histogram(image: np.ndarray, config: HistogramConfig = HistogramConfig()) -> np.ndarray:
    """Magnitude-weighted histogram of Sobel gradient angles, cells concatenated, summing to 1.

    ``image`` is grey (H, W) or BGR (H, W, 3), any numeric dtype. A blank image (no gradient at
    all) gives the uniform histogram rather than a division by zero.
    """
    gray = np.asarray(image)
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray.astype(np.float32, copy=False), cv2.COLOR_BGR2GRAY)
    gray = gray.astype(np.float32, copy=False)
    dx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    dy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    # Not cv2.magnitude: in OpenCV 5 its result depends on buffer alignment (last-ulp differences
    # between calls), which made estimates differ run to run. IEEE sqrt of exact squares does not.
    magnitude = np.sqrt(dx * dx + dy * dy)
    angle = np.arctan2(dy, dx)  # [-π, π]
    # Linear (soft) binning: each vote is shared between the two nearest bin centres, so the
    # histogram changes continuously with edge direction instead of jumping at bin edges.
    bins = config.bins
    position = (angle + np.float32(np.pi)) * np.float32(bins / (2.0 * np.pi)) - np.float32(0.5)
    lower = np.floor(position)
    upper_share = position - lower
    lower_bin = lower.astype(np.int32) % bins
    upper_bin = (lower_bin + 1) % bins
    height, width = gray.shape
    # Per column (and row band) first; columns are then shared between the two nearest cell
    # centres (bilinear), so a small pan of the camera moves weight smoothly between cells.
    row_band = (np.arange(height) * config.cells_y // height).astype(np.int32)
    column_offset = (row_band[:, None] * width + np.arange(width, dtype=np.int32)[None, :]) * bins
    upper_weight = magnitude * upper_share
    size = config.cells_y * width * bins
    per_column = np.bincount(
        (column_offset + lower_bin).ravel(), weights=(magnitude - upper_weight).ravel(), minlength=size
    ) + np.bincount((column_offset + upper_bin).ravel(), weights=upper_weight.ravel(), minlength=size)
    per_column = per_column.reshape(config.cells_y, width, bins)
    histogram = np.einsum("cw,rwb->rcb", _column_to_cell_weights(width, config.cells_x), per_column).ravel()
    total = histogram.sum()
    if not np.isfinite(total) or total <= 0.0:
        return np.full(config.length, 1.0 / config.length, dtype=np.float32)
    return (histogram / total).astype(np.float32)


@functools.lru_cache(maxsize=16)
def _column_to_cell_weights(width: int, cells: int) -> np.ndarray:
    """(cells, width) bilinear weights of each image column for each cell; columns sum to 1."""
    weights = np.zeros((cells, width))
    position = (np.arange(width) + 0.5) * cells / width - 0.5  # in cell-centre units
    left = np.floor(position).astype(int)
    share = position - left
    columns = np.arange(width)
    inside_left = left >= 0
    inside_right = left + 1 < cells
    weights[left[inside_left], columns[inside_left]] += (1.0 - share)[inside_left]
    weights[left[inside_right] + 1, columns[inside_right]] += share[inside_right]
    weights /= weights.sum(axis=0, keepdims=True)  # the outer half-cells belong wholly to the edge cell
    return weights


def chi2_distances(histogram: np.ndarray, stored: np.ndarray, eps: float = 1e-10) -> np.ndarray:
    """χ² distance of one histogram to each row of ``stored``, with ``h_i + h_j`` below the line.

    (The paper's equation 4 prints ``h_i + h_i``, a typo.) Values lie in [0, 2] for histograms
    that sum to 1.
    """
    stored = np.atleast_2d(stored)
    difference = stored - histogram
    return np.einsum("ij,ij->i", difference, difference / (stored + histogram + eps))
