"""Observation models behind one interface: the paper's histogram and the patch-normalised thumbnail."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core.config import EstimatorConfig
from aslam.core.errors import ConfigError
from aslam.core.observation import (
    INDEX_FREQUENCIES,
    INDEX_PROJECTION,
    OBSERVATION_MODELS,
    HistogramModel,
    ObservationModel,
    ObservationModelChoice,
    ThumbnailModel,
    descriptor_key,
    observation_model,
    random_projection,
)
from aslam.core.tree import NewPlaceReference


def scene(seed: int, width: int = 320, height: int = 240) -> np.ndarray:
    """A textured grey image: random blocks, smoothed (something like a wall of posters)."""
    import cv2

    rng = np.random.default_rng(seed)
    blocks = rng.uniform(0, 255, size=(height // 16, width // 8)).astype(np.float32)
    image = cv2.resize(blocks, (width, height), interpolation=cv2.INTER_NEAREST)
    return cv2.GaussianBlur(image, (5, 5), 1.5)


@pytest.mark.parametrize("model", [HistogramModel(), ThumbnailModel(), ThumbnailModel(phases=1)])
def test_both_models_fit_the_interface(model):
    assert isinstance(model, ObservationModel)
    z = model.describe(scene(1))
    assert z.dtype == np.float32 and model.view(z).shape == (model.length,)
    stored = np.stack([model.view(z), model.view(model.describe(scene(2)))])
    d = model.distances(z, stored)
    assert d.shape == (2,) and d[0] == 0.0 and d[1] > 0.0
    ll = model.log_likelihood(d)
    assert np.isfinite(ll).all() and ll[0] > ll[1]


def test_config_chooses_the_model():
    assert isinstance(observation_model(EstimatorConfig()), ThumbnailModel)
    paper = observation_model(EstimatorConfig.paper_faithful())
    assert isinstance(paper, HistogramModel) and paper.histogram.cells_x == 1


def test_a_model_registered_once_is_a_config_value_a_model_and_a_descriptor_of_its_own(monkeypatch):
    """A model is one entry of OBSERVATION_MODELS. Until 2026-12-05 it was three edits (config's
    CHOICES, and the if-chains of observation_model() and descriptor_key()), and the two chains fell
    through to the histogram: a third model left out of them ran as the histogram under its own
    name, or took the histogram's descriptor key, so a map of histogram views was taken for its own."""
    coarse = ObservationModelChoice(lambda config: ThumbnailModel(width_px=8, height_px=6))
    monkeypatch.setitem(OBSERVATION_MODELS, "coarse", coarse)
    config = EstimatorConfig(observation_model="coarse")
    assert observation_model(config) == ThumbnailModel(width_px=8, height_px=6)
    assert descriptor_key(config) == "--observation-model coarse"
    assert descriptor_key(EstimatorConfig(observation_model="histogram", cells_x=3)) == (
        "--observation-model histogram --histogram-bins 16 --cells-x 3 --cells-y 1"
    )
    with pytest.raises(ConfigError, match="must be 'histogram' or 'thumbnail' or 'coarse', got 'fine'"):
        EstimatorConfig(observation_model="fine")


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


def test_a_place_keeps_the_unshifted_view_and_a_query_holds_every_phase():
    """Only a query is described at the sub-column phases: the view a place keeps is the one-phase
    thumbnail to the bit, so maps, indexes and estimate files made with one phase stay comparable."""
    image = scene(3)
    one, four = ThumbnailModel(phases=1), ThumbnailModel(phases=4)
    query = four.describe(image)
    assert query.shape == (4 * four.length,)
    np.testing.assert_array_equal(four.view(query), one.describe(image))
    assert not np.array_equal(query[four.length : 2 * four.length], query[: four.length])


@pytest.mark.parametrize("pan_px", [10, -10, 5, -15])
def test_a_pan_by_a_fraction_of_a_column_lines_up_at_a_phase(pan_px):
    """Half a column (10 of the 320 pixels' 20 a column) off: whole-column shifts leave every column
    half wrong (0.77, near another place's 1.0); one of the query's phases lines it up."""
    image, panned = scene(5), np.roll(scene(5), pan_px, axis=1)
    one, four = ThumbnailModel(phases=1), ThumbnailModel(phases=4)
    before = one.distances(one.describe(panned), one.describe(image)[None])[0]
    now = four.distances(four.describe(panned), four.view(four.describe(image))[None])[0]
    other = four.distances(four.describe(image), four.view(four.describe(scene(6)))[None])[0]
    assert now < 0.25 * before and now < 0.1 * other


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**16), st.integers(0, 2**16), st.integers(-40, 40))
def test_more_phases_never_make_a_view_less_alike(seed, other_seed, pan_px):
    """A distance is the least over the query's phases, its unshifted view among them."""
    model = ThumbnailModel(phases=4)
    query = model.describe(np.roll(scene(seed), pan_px, axis=1))
    stored = np.stack([model.view(model.describe(scene(s))) for s in (seed, other_seed)])
    assert (model.distances(query, stored) <= model.distances(model.view(query), stored)).all()


def described_one_phase_at_a_time(model: ThumbnailModel, gray: np.ndarray) -> np.ndarray:
    """The thumbnail as it was first written: each phase resized, moved and normalised on its own."""
    import cv2

    image = gray.astype(np.float32)
    w, h, p = model.width_px, model.height_px, model.phases

    def normalised(small: np.ndarray) -> np.ndarray:
        small = small.astype(np.float64)
        size = (model.patch_px, model.patch_px)
        mean = cv2.blur(small, size, borderType=cv2.BORDER_REFLECT)
        mean_sq = cv2.blur(small * small, size, borderType=cv2.BORDER_REFLECT)
        std = np.sqrt(np.maximum(mean_sq - mean * mean, 0))
        return ((small - mean) / np.maximum(std, 1.0)).astype(np.float32).ravel()

    views = [normalised(cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA))]
    fine = cv2.resize(image, (w * p, h), interpolation=cv2.INTER_AREA)
    for k in range(1, p):
        moved = np.concatenate([fine[:, k:], np.repeat(fine[:, -1:], k, axis=1)], axis=1)
        views.append(normalised(moved.reshape(h, w, p).mean(axis=2)))
    return np.concatenate(views)


def distances_one_shift_at_a_time(model: ThumbnailModel, query: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """Each stored view against each phase at each shift, the mean over the columns both hold."""
    h, w = model.height_px, model.width_px
    best = np.full(len(stored), np.inf)
    for i, row in enumerate(stored.reshape(-1, h, w)):
        for phase in query.reshape(-1, h, w):
            for shift in range(-model.max_shift_px, model.max_shift_px + 1):
                if shift >= 0:
                    a, b = phase[:, shift:], row[:, : w - shift]
                else:
                    a, b = phase[:, :shift], row[:, -shift:]
                best[i] = min(best[i], np.add.reduce(np.abs(b - a), axis=None, dtype=np.float64) / a.size)
    return best


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 2**16),
    st.sampled_from([(320, 240), (64, 32), (53, 37), (640, 480)]),
    st.integers(1, 8),
    st.integers(0, 5),
)
def test_the_thumbnail_is_the_same_to_the_bit_as_one_phase_and_one_shift_at_a_time(seed, size, phases, rows):
    """describe() normalises its phases as channels of one image, and distances() takes every shift's
    sums before one division: fewer calls (docs/estimator.md, "Shifts by a fraction of a column"),
    and bit for bit the arithmetic of one phase, one shift at a time, so maps and estimates made
    before are read the same."""
    model = ThumbnailModel(phases=phases)
    rng = np.random.default_rng(seed)
    gray = noisy_ramp(rng, size)
    query = model.describe(gray)
    np.testing.assert_array_equal(query, described_one_phase_at_a_time(model, gray))
    others = [model.view(model.describe(noisy_ramp(rng, size))) for _ in range(rows)]
    stored = np.stack([*others, model.view(query)])
    expected = distances_one_shift_at_a_time(model, query, stored)
    np.testing.assert_array_equal(model.distances(query, stored), expected)


def noisy_ramp(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """uint8 noise over a gradient: a view with texture at every scale, of ``size`` (width, height)."""
    width, height = size
    ramp = np.linspace(0, 200, width)[None, :] + np.linspace(0, 50, height)[:, None]
    return np.clip(ramp + rng.normal(0, 30, (height, width)), 0, 255).astype(np.uint8)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**16), st.integers(-15, 15))
def test_thumbnail_index_key_has_a_part_blind_to_a_sideways_shift(seed, shift):
    """The shift-blind part of a view's index key and of the same view shifted sideways (circularly)
    are one; the other part keeps where things are, so it moves."""
    model = ThumbnailModel()
    view = np.random.default_rng(seed).standard_normal(model.length).astype(np.float32)
    rows = view.reshape(model.height_px, model.width_px)
    key = model.index_key(view)
    assert key.dtype == np.float32 and key.shape == (sum(model.index_key_parts),)
    shifted = model.index_key(np.roll(rows, shift, axis=1).ravel())
    blind = model.height_px * INDEX_FREQUENCIES
    np.testing.assert_allclose(shifted[:blind], key[:blind], rtol=1e-4, atol=1e-4)
    if shift % model.width_px:
        assert not np.allclose(shifted[blind:], key[blind:], atol=1e-3)


def test_a_place_seen_panned_is_shortlisted_by_the_relocalisation_index():
    """Views panned 1–4 thumbnail columns (4–15°) from the stored ones: the key's shift-blind part
    shortlists the place most times, the thumbnail randomly projected (the index's key before)
    rarely; the index searches both parts."""
    from aslam.core.place_index import PlaceIndex

    model = ThumbnailModel()
    blind_length = model.index_key_parts[0]
    stored = [model.view(model.describe(scene(seed))) for seed in range(200)]
    indexes = {
        "blind": PlaceIndex((blind_length,), skip=0, key=lambda view: model.index_key(view)[:blind_length]),
        "projected": PlaceIndex(
            (INDEX_PROJECTION,), skip=0, key=lambda view: random_projection(model.length) @ view
        ),
        "both": PlaceIndex(model.index_key_parts, skip=0, key=model.index_key),
    }
    for state, view in enumerate(stored):
        for index in indexes.values():
            index.add(state, view)
    found = dict.fromkeys(indexes, 0)
    queries = [(seed, columns) for seed in range(0, 200, 5) for columns in (1, 2, 3, 4)]
    for seed, columns in queries:
        # A pan: the scene moves sideways and new content enters at the edge (not a roll).
        wide = np.concatenate([scene(seed), scene(1000 + seed)], axis=1)
        panned = model.view(model.describe(wide[:, columns * 320 // model.width_px :][:, :320]))
        for name, index in indexes.items():
            found[name] += seed in index.search(panned, 200, 12).tolist()
    assert found["blind"] >= 0.9 * len(queries)  # 154 of 160
    assert found["projected"] < 0.1 * len(queries)  # 4 of 160
    assert found["both"] >= found["blind"]


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


def test_a_black_frame_is_not_recognisable_and_real_frames_are():
    """Black frames have no contrast to be found by: one of the 17 that open Nordland's summer
    journey, and a 320 × 240 camera's with its lens capped (noise σ 3 grey levels). Real frames,
    and the same frames darkened tenfold, do."""
    from pathlib import Path

    import cv2

    data = Path(__file__).parent / "data"
    model = ThumbnailModel()
    rng = np.random.default_rng(0)
    nordland_black = cv2.imread(str(data / "blank" / "nordland-summer-00010.png"), cv2.IMREAD_GRAYSCALE)
    capped = np.clip(rng.normal(8.0, 3.0, (240, 320)), 0, 255).astype(np.uint8)
    for black in (nordland_black, capped):
        assert not model.recognisable(model.describe(black))
    frames = sorted((data / "nordland").glob("*/images-*.png"))
    assert len(frames) == 60
    for frame in frames:
        image = cv2.imread(str(frame), cv2.IMREAD_GRAYSCALE)
        assert model.recognisable(model.describe(image))
        dark = (image.astype(np.float32) * 0.1 + rng.normal(0, 1.0, image.shape)).clip(0, 255)
        assert model.recognisable(model.describe(dark.astype(np.uint8)))
