"""The relocalisation index: committed places, searchable by appearance at a cost that stays
small as the map grows.

Each place is kept as its first view's key (the observation model's ``index_key``: short vectors,
its parts, whose cosine similarities rank views roughly as the model's distance does), each part
L2-normalised (so the inner product is the cosine similarity) and searched on its own. Up to
``EXACT_LIMIT`` places a query is one exact matrix–vector product per part. Beyond, a scan would
grow with the map, so each part moves into an inverted file (faiss's ``IndexIVFFlat``): the places
are sorted into cells around k-means centroids, and a query scans the ``CELLS_SEARCHED`` nearest
cells only. The cells are laid out again whenever the map has grown ``REFIT_GROWTH`` times since
they were, with √(``CELLS_SEARCHED`` × places) cells (which makes the centroids and the searched
cells equal work), so a query costs O(√places). faiss is imported only then. The index only
shortlists: the observation model compares the shortlist exactly, so an approximate answer can
miss a candidate but never make a claim.

Why cells rather than a graph (HNSW, which this index was until 2026-12): a SLAM step leaves the
index cold in the caches, and a graph's search hops through memory at random while a cell is one
contiguous run. Measured at 100,000 keyframes (40,746 places, two key parts): the graph's queries
and insertions cost 0.29 ms a step, the cells' 0.12; the true place of a revisit was shortlisted
as often (docs/estimator.md, "Relocalisation").
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from aslam.core.mapgraph import GrowableArray

EXACT_LIMIT = 2048
"""Places up to which the index is searched exactly. Measured (a 36-dimension part, one query, in a
loop): the scan with its partial sort costs 0.06 ms at 4,000 places and 0.49 ms at 40,000; the
cells 0.03 ms at 15,750. Small maps stay exact (every rendered recording and Nordland's journey
do); laying out the first cells costs 0.02 s."""
CELLS_SEARCHED = 24
"""Cells a query scans (faiss's ``nprobe``). On the keys of 270 rendered recordings (15,750
places, 4,259 revisits) the true place was shortlisted for 0.828 of revisits with 24 cells, 0.820
with 16, 0.831 with 32; 0.825 by the HNSW graph this index used before, 0.830 by the exact scan."""
REFIT_GROWTH = 4
"""The cells are laid out again (k-means, 10 rounds) once the map has grown this many times since
they were: at 8,192 places 0.03 s a part, at 32,768 about 0.5 s."""


class PlaceIndex:
    """The places of the committed map by appearance; a place becomes searchable ``skip`` keyframes
    after it is first seen (until then the motion model covers it).

    Deterministic: the exact scan is single-threaded ``einsum`` (a fixed summation order); the
    cells come from seeded k-means on one thread over the places in state order.
    """

    def __init__(
        self,
        key_parts: tuple[int, ...],
        skip: int,
        *,
        key: Callable[[np.ndarray], np.ndarray] | None = None,
        exact_limit: int = EXACT_LIMIT,
    ) -> None:
        """``key`` makes an observation's index key: parts of ``key_parts`` lengths, one after the
        other, each searched on its own (None: the observation is its key, one part)."""
        self._key = key
        self._skip = skip
        self._exact_limit = exact_limit
        bounds = np.cumsum((0, *key_parts)).tolist()
        self._parts = [slice(a, b) for a, b in itertools.pairwise(bounds)]
        self._vectors = [GrowableArray((part,), np.float32) for part in key_parts]
        self._states = GrowableArray((), np.int64)
        self._waiting: deque[tuple[int, list[np.ndarray]]] = deque()
        self._cells: list[Any] | None = None
        self._fitted_at = 0

    @property
    def approximate(self) -> bool:
        """Whether queries go to the cells (the map outgrew ``exact_limit``)."""
        return self._cells is not None

    def add(self, state: int, observation: np.ndarray, *, searchable: bool = False) -> None:
        """A newly committed place (states arrive in increasing order: a state is its first keyframe).

        ``searchable`` skips the wait: a prior session's places are not recent in this one.
        """
        if searchable and not self._waiting and self._cells is None:
            for vectors, part in zip(self._vectors, self._key_of(observation), strict=True):
                vectors.append(part)
            self._states.append(state)
            return
        self._waiting.append((state, self._key_of(observation)))

    def search(self, observation: np.ndarray, keyframes: int, count: int) -> np.ndarray:
        """Places most like ``observation`` by any part of the key, ``count`` per part (so up to
        ``count`` × parts, in increasing order), among those first seen at least ``skip`` keyframes
        before keyframe ``keyframes``."""
        arriving: list[list[np.ndarray]] = [[] for _ in self._vectors]
        while self._waiting and self._waiting[0][0] < keyframes - self._skip:
            state, parts = self._waiting.popleft()
            for vectors, part, batch in zip(self._vectors, parts, arriving, strict=True):
                vectors.append(part)
                batch.append(part)
            self._states.append(state)
        searchable = len(self._states)
        if not searchable:
            return np.zeros(0, np.int64)
        count = min(count, searchable)
        query = self._key_of(observation)
        found: set[int] = set()
        if searchable <= self._exact_limit:  # (cells, once made, only come with more places)
            for vectors, part in zip(self._vectors, query, strict=True):
                # einsum, not BLAS: single-threaded and summed in a fixed order (same bytes every run).
                similarity = np.einsum("ij,j->i", vectors.view, part)
                found.update(self._states.view[np.argpartition(-similarity, count - 1)[:count]].tolist())
            return np.array(sorted(found), dtype=np.int64)
        with _one_faiss_thread():
            if self._cells is not None and arriving[0]:
                for cells, batch in zip(self._cells, arriving, strict=True):
                    cells.add(np.stack(batch))  # one call per part: a faiss call costs more than a place
            if self._cells is None or searchable >= REFIT_GROWTH * self._fitted_at:
                self._cells = [_cells_of(vectors.view) for vectors in self._vectors]
                self._fitted_at = searchable
            for cells, part in zip(self._cells, query, strict=True):
                _, rows = cells.search(part[None, :], count)
                found.update(self._states.view[rows[0][rows[0] >= 0]].tolist())
        return np.array(sorted(found), dtype=np.int64)

    def _key_of(self, observation: np.ndarray) -> list[np.ndarray]:
        """The key's parts, each L2-normalised (its inner products are cosines)."""
        key = np.asarray(observation if self._key is None else self._key(observation), dtype=np.float32)
        parts = []
        for part in self._parts:
            vector = key[part]
            norm = float(np.linalg.norm(vector))
            parts.append((vector / norm if norm > 0 else vector).astype(np.float32))
        return parts


@contextmanager
def _one_faiss_thread() -> Iterator[None]:
    """faiss on one OpenMP thread, its count put back after (a setting of the whole process: a
    caller's own faiss work stays as it was). One query and one insertion at a time: OpenMP's
    threads only add hand-offs (measured with the earlier HNSW index, a query and an insertion a
    step at 40,000 places: 0.32 ms with two threads, 0.24 ms with one)."""
    import faiss

    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(1)
    try:
        yield
    finally:
        faiss.omp_set_num_threads(before)


def _cells_of(vectors: np.ndarray) -> Any:
    """An inverted file (inner product) holding ``vectors`` in √(``CELLS_SEARCHED`` × places) cells."""
    import faiss

    dimensions = vectors.shape[1]
    cells = max(1, min(len(vectors), round(math.sqrt(CELLS_SEARCHED * len(vectors)))))
    quantiser = faiss.IndexFlatIP(dimensions)  # the inverted file keeps a reference to it
    index = faiss.IndexIVFFlat(quantiser, dimensions, cells, faiss.METRIC_INNER_PRODUCT)
    index.cp.seed = 1
    index.cp.niter = 10
    index.cp.spherical = True  # centroids on the unit sphere, as the keys are
    index.cp.min_points_per_centroid = 1  # few places per cell is expected; faiss would warn
    index.train(vectors)
    index.add(vectors)
    index.nprobe = CELLS_SEARCHED
    return index
