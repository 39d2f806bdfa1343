"""Gradient-orientation histograms and the χ² distance."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aslam.core.features import HistogramConfig, chi2_distances, orientation_histogram

histograms = (
    arrays(np.float64, 12, elements=st.floats(0.0, 1.0))
    .filter(lambda h: h.sum() > 1e-3)
    .map(lambda h: h / h.sum())
)
images = arrays(np.uint8, (24, 32), elements=st.integers(0, 255))
configs = st.builds(
    HistogramConfig, bins=st.sampled_from([4, 8, 16]), cells_x=st.integers(1, 4), cells_y=st.integers(1, 3)
)


@given(histograms)
def test_chi2_is_zero_on_identical_histograms(h):
    assert chi2_distances(h, h[None, :])[0] == 0.0


@given(histograms, histograms)
def test_chi2_is_symmetric_and_non_negative(a, b):
    ab = chi2_distances(a, b[None, :])[0]
    ba = chi2_distances(b, a[None, :])[0]
    assert ab >= 0.0
    assert math.isclose(ab, ba, rel_tol=1e-9, abs_tol=1e-12)
    assert ab <= 2.0 + 1e-9


@given(histograms, st.lists(histograms, min_size=1, max_size=5))
def test_chi2_is_vectorised_row_by_row(h, rows):
    stacked = np.array(rows)
    together = chi2_distances(h, stacked)
    one_by_one = [chi2_distances(h, r[None, :])[0] for r in rows]
    np.testing.assert_allclose(together, one_by_one)


@settings(max_examples=50)
@given(images, configs)
def test_histograms_sum_to_one(image, config):
    h = orientation_histogram(image, config)
    assert h.shape == (config.length,)
    assert math.isclose(float(h.sum()), 1.0, rel_tol=1e-5)
    assert (h >= 0).all()


@settings(max_examples=50)
@given(images, configs, st.floats(0.05, 20.0))
def test_histograms_ignore_uniform_brightness_scaling(image, config, scale):
    base = orientation_histogram(image.astype(np.float32), config)
    scaled = orientation_histogram(image.astype(np.float32) * scale, config)
    np.testing.assert_allclose(base, scaled, atol=1e-5)


def test_orientation_bins_follow_edge_direction():
    ramp = np.tile(np.arange(64, dtype=np.float32), (48, 1))  # brightness grows along +x
    h = orientation_histogram(ramp, HistogramConfig(bins=8))
    # Gradient angle 0 lies on the edge between bins 3 and 4 of [-π, π): soft binning splits it.
    np.testing.assert_allclose(h[[3, 4]], [0.5, 0.5], atol=1e-3)
    rows, cols = np.mgrid[0:48, 0:64].astype(np.float32)
    tilted = cols * np.cos(np.pi / 8) + rows * np.sin(np.pi / 8)  # gradient at 22.5°: centre of bin 4
    assert orientation_histogram(tilted, HistogramConfig(bins=8))[4] > 0.95


def test_blank_image_gives_uniform_histogram():
    h = orientation_histogram(np.full((20, 20), 128, np.uint8), HistogramConfig(bins=8, cells_x=2))
    np.testing.assert_allclose(h, np.full(16, 1 / 16))


def test_spatial_cells_separate_mirrored_layouts():
    left = np.zeros((40, 80), np.float32)
    left[:, 10:30] = np.tile(np.arange(20, dtype=np.float32), (40, 1))
    right = left[:, ::-1].copy()
    right[:, 50:70] = left[:, 10:30]
    right[:, 10:30] = 0
    single = HistogramConfig(bins=8)
    cells = HistogramConfig(bins=8, cells_x=2)
    same_globally = chi2_distances(
        orientation_histogram(left, single), orientation_histogram(right, single)[None]
    )[0]
    apart_by_cells = chi2_distances(
        orientation_histogram(left, cells), orientation_histogram(right, cells)[None]
    )[0]
    assert same_globally < 1e-6 < 0.5 < apart_by_cells
