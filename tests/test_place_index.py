"""The relocalisation index: exact on small maps, an inverted file on large ones, only places old enough,
deterministic."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core.observation import ThumbnailModel
from aslam.core.place_index import CELLS_SEARCHED, PlaceIndex


def _views(count: int, length: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((count, length)).astype(np.float32)


def _cosine_top(views: np.ndarray, query: np.ndarray, index: PlaceIndex, count: int) -> set[int]:
    projected = np.array([index._key_of(v)[0] for v in views])
    similarity = projected @ index._key_of(query)[0]
    return set(np.argsort(-similarity, kind="stable")[:count].tolist())


@settings(max_examples=40, deadline=None)
@given(
    places=st.integers(1, 60),
    length=st.sampled_from([16, 32, 192]),
    skip=st.integers(0, 15),
    count=st.integers(1, 12),
    seed=st.integers(0, 2**16),
    exact_limit=st.sampled_from([4096, 8]),
)
def test_small_maps_give_the_exact_most_similar_old_enough_places(
    places, length, skip, count, seed, exact_limit
):
    """Exact by scan, and by the inverted file too while it searches every cell (a map of at most
    ``CELLS_SEARCHED`` places has no more cells than that)."""
    if exact_limit < places:
        places = min(places, CELLS_SEARCHED)
    views = _views(places, length, seed)
    index = PlaceIndex((length,), skip, exact_limit=exact_limit)
    for state, view in enumerate(views):
        index.add(state, view)
    keyframes = places + 3
    query = views[seed % places] + 0.1 * _views(1, length, seed + 1)[0]
    found = index.search(query, keyframes, count)
    old_enough = np.arange(places)[np.arange(places) < keyframes - skip]
    assert set(found.tolist()) <= set(old_enough.tolist())
    assert len(found) == min(count, len(old_enough))
    if len(old_enough):
        assert set(found.tolist()) == _cosine_top(views[old_enough], query, index, count)


def test_a_place_is_searchable_only_skip_keyframes_after_it_is_seen():
    views = _views(5, 32, 0)
    index = PlaceIndex((32,), skip=10)
    for state, view in enumerate(views):
        index.add(state, view)
    assert len(index.search(views[0], keyframes=10, count=3)) == 0
    assert index.search(views[0], keyframes=11, count=3).tolist() == [0]
    assert set(index.search(views[4], keyframes=15, count=5).tolist()) == {0, 1, 2, 3, 4}


def test_a_large_map_moves_into_cells_and_answers_the_same_every_time():
    """With the default (thumbnail) model's keys."""
    model = ThumbnailModel()
    views = _views(3000, model.length, 7)
    queries = range(0, 3000, 97)

    def answers() -> tuple[list[list[int]], bool]:
        index = PlaceIndex(model.index_key_parts, skip=0, key=model.index_key, exact_limit=1000)
        for state, view in enumerate(views):
            index.add(state, view)
        found = [index.search(views[i] + 0.05, 3001, 12).tolist() for i in queries]
        return found, index.approximate

    first, approximate = answers()
    assert approximate
    assert (first, approximate) == answers()
    exact = PlaceIndex(model.index_key_parts, skip=0, key=model.index_key, exact_limit=10_000)
    for state, view in enumerate(views):
        exact.add(state, view)
    overlap = [
        len(set(row) & set(exact.search(views[i] + 0.05, 3001, 12).tolist())) / len(row)
        for row, i in zip(first, queries, strict=True)
    ]
    # Unstructured random views are the cells' hardest case (a view's neighbours lie in any cell):
    # most of the exact shortlist, and always the place itself.
    assert np.mean(overlap) >= 0.75
    assert all(i in row for row, i in zip(first, queries, strict=True))


def test_the_cells_leave_faiss_s_thread_count_as_it_was():
    """faiss's OpenMP thread count is the whole process's: the index sets one thread for its own
    calls and puts the count back (it was left at one: a caller's faiss work after an estimate ran
    on one thread)."""
    import faiss

    faiss.omp_set_num_threads(3)
    index = PlaceIndex((8,), skip=0, exact_limit=16)
    rng = np.random.default_rng(0)
    for state in range(40):
        index.add(state, rng.random(8).astype(np.float32))
    assert len(index.search(rng.random(8).astype(np.float32), 40, 3)) == 3 and index.approximate
    assert faiss.omp_get_max_threads() == 3
