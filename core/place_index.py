"""The relocalisation index: committed places, searchable by appearance at a cost that stays
bounded as the map grows.

Each place is kept as its first view's key (the observation model's ``index_key``: short vectors,
its parts, whose cosine similarities rank views roughly as the model's distance does), each part
L2-normalised (so the inner product is the cosine similarity) and searched on its own. Up to
``EXACT_LIMIT`` places a query is one exact matrix–vector product per part. Beyond, a scan would
grow with the map — at 40,000 places it took 1.1 of the 2.7 ms a SLAM step cost — so the index
moves into an HNSW graph per part (Malkov & Yashunin; faiss's ``IndexHNSWFlat``), which answers in
O(log places); faiss is imported only then. The index only shortlists: the observation model
compares the shortlist exactly, so an approximate answer can miss a candidate but never make a
claim.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from aslam.core.mapgraph import GrowableArray

EXACT_LIMIT = 8192
"""Places up to which the index is searched exactly. Measured (32 dimensions, one query): the scan
costs 0.026 ms at 2,048 places, 0.086 ms at 8,192 and 0.15 ms at 12,288; the graph 0.04 ms a
query at 10,000 places and 0.065 ms at 100,000 in a loop of queries (0.16 ms in a run, the graph
cold in the caches after the rest of a step), plus 0.055 ms to insert each new place. So the scan
stays below the graph up to about here; moving into the graph costs once 0.45 s."""
NEIGHBOURS_PER_NODE = 16
"""HNSW's M: links per place in the graph (2 × M × 4 bytes per place on top of its view)."""
SEARCH_BREADTH = 64
"""HNSW's efSearch floor: candidates kept while searching; well above the shortlist, near-exact."""


class PlaceIndex:
    """The places of the committed map by appearance; a place becomes searchable ``skip`` keyframes
    after it is first seen (until then the motion model covers it).

    Deterministic: the exact scan is single-threaded ``einsum`` (a fixed summation order); the
    HNSW graph takes the places one at a time, in state order, and draws its levels from its own
    seeded generator.
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
        self._hnsw: list[Any] | None = None

    @property
    def approximate(self) -> bool:
        """Whether queries go to the HNSW graphs (the map outgrew ``exact_limit``)."""
        return self._hnsw is not None

    def add(self, state: int, observation: np.ndarray, *, searchable: bool = False) -> None:
        """A newly committed place (states arrive in increasing order: a state is its first keyframe).

        ``searchable`` skips the wait: a prior session's places are not recent in this one.
        """
        if searchable and not self._waiting and self._hnsw is None:
            for vectors, part in zip(self._vectors, self._key_of(observation), strict=True):
                vectors.append(part)
            self._states.append(state)
            return
        self._waiting.append((state, self._key_of(observation)))

    def search(self, observation: np.ndarray, keyframes: int, count: int) -> np.ndarray:
        """Places most like ``observation`` by any part of the key, ``count`` per part (so up to
        ``count`` × parts, in increasing order), among those first seen at least ``skip`` keyframes
        before keyframe ``keyframes``."""
        while self._waiting and self._waiting[0][0] < keyframes - self._skip:
            state, parts = self._waiting.popleft()
            for index, (vectors, part) in enumerate(zip(self._vectors, parts, strict=True)):
                vectors.append(part)
                if self._hnsw is not None:
                    self._hnsw[index].add(part[None, :])
            self._states.append(state)
        searchable = len(self._states)
        if not searchable:
            return np.zeros(0, np.int64)
        count = min(count, searchable)
        query = self._key_of(observation)
        found: set[int] = set()
        if searchable <= self._exact_limit:
            for vectors, part in zip(self._vectors, query, strict=True):
                # einsum, not BLAS: single-threaded and summed in a fixed order (same bytes every run).
                similarity = np.einsum("ij,j->i", vectors.view, part)
                found.update(self._states.view[np.argpartition(-similarity, count - 1)[:count]].tolist())
        else:
            if self._hnsw is None:
                self._hnsw = [_hnsw_of(vectors.view) for vectors in self._vectors]
            for graph, part in zip(self._hnsw, query, strict=True):
                graph.hnsw.efSearch = max(SEARCH_BREADTH, count)
                _, rows = graph.search(part[None, :], count)
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


def _hnsw_of(vectors: np.ndarray) -> Any:
    """An HNSW graph (inner product) holding ``vectors``, added one at a time in order."""
    import faiss

    # One query and one insertion at a time: OpenMP's threads only add hand-offs (measured, a query
    # and an insertion a step at 40,000 places: 0.32 ms with two threads, 0.24 ms with one).
    faiss.omp_set_num_threads(1)
    graph = faiss.IndexHNSWFlat(vectors.shape[1], NEIGHBOURS_PER_NODE, faiss.METRIC_INNER_PRODUCT)
    for vector in vectors:
        graph.add(vector[None, :])
    return graph
