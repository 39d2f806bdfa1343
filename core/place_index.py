"""The relocalisation index: committed places, searchable by appearance at a cost that does not grow
with the map.

A linear scan of every place's view costs O(places) per keyframe: at 40,000 places it took 1.1 of
the 2.7 ms a SLAM step cost. An HNSW graph (Malkov & Yashunin; faiss's ``IndexHNSWFlat``) answers
a nearest-neighbour query in O(log places). The index holds each place's first view, projected to
``INDEX_LENGTH`` dimensions and L2-normalised, so the inner product is the cosine similarity. It
only shortlists: the observation model then compares the shortlist exactly, so an approximate
answer can miss a candidate but never make a claim.
"""

from __future__ import annotations

import math
from collections import deque

import faiss
import numpy as np

from aslam.core.mapgraph import GrowableArray

INDEX_LENGTH = 32
"""Dimensions of the index: observations longer than this are projected."""
NEIGHBOURS_PER_NODE = 16
"""HNSW's M: links per place in the graph (memory ≈ 2 × M × 4 bytes per place on top of the view)."""
SEARCH_BREADTH = 64
"""HNSW's efSearch floor: candidates kept while searching; well above the shortlist, near-exact."""


class PlaceIndex:
    """The places of the committed map by appearance; a place becomes searchable ``skip`` keyframes
    after it is first seen (until then the motion model covers it).

    Deterministic: places are added one at a time, in state order, and HNSW's level draws come
    from its own seeded generator.
    """

    def __init__(self, observation_length: int, skip: int) -> None:
        self._projection = _projection(observation_length)
        self._skip = skip
        self._hnsw = faiss.IndexHNSWFlat(
            len(self._projection), NEIGHBOURS_PER_NODE, faiss.METRIC_INNER_PRODUCT
        )
        self._states = GrowableArray((), np.int64)
        self._waiting: deque[tuple[int, np.ndarray]] = deque()

    def __len__(self) -> int:
        return len(self._states) + len(self._waiting)

    def add(self, state: int, observation: np.ndarray) -> None:
        """A newly committed place (states arrive in increasing order: a state is its first keyframe)."""
        self._waiting.append((state, self._project(observation)))

    def search(self, observation: np.ndarray, keyframes: int, count: int) -> np.ndarray:
        """Up to ``count`` places most like ``observation`` among those first seen at least ``skip``
        keyframes before keyframe ``keyframes``."""
        while self._waiting and self._waiting[0][0] < keyframes - self._skip:
            state, vector = self._waiting.popleft()
            self._hnsw.add(vector[None, :])
            self._states.append(state)
        if not len(self._states):
            return np.zeros(0, np.int64)
        self._hnsw.hnsw.efSearch = max(SEARCH_BREADTH, count)
        _, found = self._hnsw.search(self._project(observation)[None, :], min(count, len(self._states)))
        found = found[0]
        return self._states.view[found[found >= 0]]

    def _project(self, observation: np.ndarray) -> np.ndarray:
        vector = self._projection @ np.asarray(observation, dtype=np.float32)
        norm = float(np.linalg.norm(vector))
        return (vector / norm if norm > 0 else vector).astype(np.float32)


def _projection(length: int) -> np.ndarray:
    """A fixed random projection (Johnson–Lindenstrauss) to ``INDEX_LENGTH`` dimensions, or the identity.

    Angles between vectors are nearly kept, so the most similar places by the index are, with
    few exceptions, the most similar by the model; the model then compares the shortlist exactly.
    """
    if length <= INDEX_LENGTH:
        return np.eye(length, dtype=np.float32)
    rng = np.random.default_rng(20261129)
    return (rng.standard_normal((INDEX_LENGTH, length)) / math.sqrt(INDEX_LENGTH)).astype(np.float32)
