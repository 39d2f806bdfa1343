"""Observation models behind one interface: the paper's histogram and the patch-normalised thumbnail."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core.config import EstimatorConfig
from aslam.core.observation import HistogramModel, ObservationModel, ThumbnailModel, observation_model
from aslam.core.tree import NewPlaceReference


def scene(seed: int, width: int = 320, height: int = 240) -> np.ndarray:
    """A textured grey image: random blocks, smoothed (something like a wall of posters)."""
    import cv2

    rng = np.random.default_rng(seed)
    blocks = rng.uniform(0, 255, size=(height // 16, width // 8)).astype(np.float32)
    image = cv2.resize(blocks, (width, height), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(image, (5, 5), 1.5)


@pytest.mark.parametrize("model", [HistogramModel(), ThumbnailModel()])
def test_both_models_fit_the_interface(model):
    assert isinstance(model, ObservationModel)
    z = model.describe(scene(1))
    assert z.dtype == np.float32 and z.shape == (model.length,)
    stored = np.stack([z, model.describe(scene(2))])
    d = model.distances(z, stored)
    assert d.shape == (2,) and d[0] == 0.0 and d[1] > 0.0
    ll = model.log_likelihood(d)
    assert np.isfinite(ll).all() and ll[0] > ll[1]


def test_config_chooses_the_model():
    assert isinstance(observation_model(EstimatorConfig()), ThumbnailModel)
    paper = observation_model(EstimatorConfig.paper_faithful())
    assert isinstance(paper, HistogramModel) and paper.histogram.cells_x == 1


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 1000), st.floats(0.3, 3.0), st.floats(-60, 60))
def test_thumbnail_ignores_brightness_and_contrast(seed, gain, offset):
    model = ThumbnailModel()
    image = scene(seed)
    relit = np.clip(image * gain + offset + 100, -1e6, 1e6)
    a, b = model.describe(image + 100), model.describe(relit)
    assert model.distances(a, b[None])[0] < 0.05


def test_thumbnail_tolerates_a_small_pan_and_tells_places_apart():
    """A view panned by 2 thumbnail columns (7.5° of 60°) is closer than another place."""
    model = ThumbnailModel()
    image = scene(5)
    panned = np.roll(image, 2 * 320 // model.width_px, axis=1)
    same = model.distances(model.describe(image), model.describe(panned)[None])[0]
    other = model.distances(model.describe(image), model.describe(scene(6))[None])[0]
    rigid = ThumbnailModel(max_shift_px=0)
    rigid_same = rigid.distances(rigid.describe(image), rigid.describe(panned)[None])[0]
    assert same < 0.3 * other and same < 0.5 * rigid_same


def test_new_place_reference_is_fixed_until_it_has_seen_enough():
    reference = NewPlaceReference(fixed=0.5, scale=0.75, floor=0.02, window=4, warmup=3)
    reference.observe(0.8)
    reference.observe(0.9)
    assert reference.value == 0.5
    for d in (1.0, 2.0, 2.0):  # the window keeps the last four: 0.9, 1, 2, 2
        reference.observe(d)
    assert reference.value == pytest.approx(0.75 * 1.5)
    assert NewPlaceReference(fixed=0.5, scale=0.0, floor=0.02).value == 0.5  # scale 0: always fixed


def test_a_robot_standing_still_does_not_drive_the_reference_to_zero():
    """Identical consecutive views (a stop, a repeated frame) say nothing about neighbouring places."""
    reference = NewPlaceReference(fixed=0.5, scale=1.0, floor=0.02, window=10, warmup=3)
    for d in (0.4, 0.0, 0.0, 0.01, 0.0, 0.6, 0.0, 0.5):
        reference.observe(d)
    assert reference.value == pytest.approx(0.5)
