"""The map all hypotheses agree on: places (states) joined by links, with no global frame.

A state's id is the index of the keyframe that first observed it, so every hypothesis that
calls keyframe t a new place names it the same way. A link stores the relative pose (with
covariance) from one state to another as measured by odometry; walking it backwards inverts it,
traversing it again fuses the new measurement in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from aslam.core.motion import Rel, fuse_rel, inverse_rel, link_weight


@dataclass(frozen=True)
class PriorMap:
    """A map an earlier session built, to start a new session in (multi-session mapping).

    The new session numbers its keyframes from ``keyframes`` on, so state ids (first-visit
    keyframes) stay unique across sessions and the extended map can itself be the next prior.
    """

    keyframes: int
    """Keyframes of the earlier sessions: the new session's first keyframe index."""
    state_of_keyframe: np.ndarray
    """(keyframes,) int64: the place of each earlier keyframe."""
    states: np.ndarray
    """(P,) int64 state ids, ascending."""
    views: np.ndarray
    """(P, observation length) float32: the view stored with each state, row for row."""
    links: tuple[tuple[int, int, Rel, int], ...]
    """(from_state, to_state, rel, traversals) of each link."""


@dataclass
class LinkRecord:
    """A link as first traversed: ``from_state → to_state``, how often it was driven."""

    from_state: int
    to_state: int
    rel: Rel
    count: int


class SharedMap:
    """States and links committed from the history every hypothesis shares.

    ``adjacency[a][b]`` is ``(rel, weight)``: b seen from a, and the link's scalar uncertainty
    that the graph search sums (see :func:`aslam.core.motion.link_weight`).
    """

    def __init__(self) -> None:
        self.states: set[int] = set()
        self.adjacency: dict[int, dict[int, tuple[Rel, float]]] = {}
        self.links: dict[tuple[int, int], LinkRecord] = {}

    def copy(self) -> SharedMap:
        other = SharedMap()
        other.states = set(self.states)
        other.adjacency = {state: dict(neighbours) for state, neighbours in self.adjacency.items()}
        other.links = {
            key: LinkRecord(link.from_state, link.to_state, link.rel, link.count)
            for key, link in self.links.items()
        }
        return other

    def add_state(self, state: int) -> None:
        self.states.add(state)
        self.adjacency.setdefault(state, {})

    def add_link(self, from_state: int, to_state: int, rel: Rel, count: int) -> None:
        """Restore a link as a stored map has it (a prior session's map)."""
        key = (min(from_state, to_state), max(from_state, to_state))
        self.links[key] = LinkRecord(from_state, to_state, rel, count)
        weight = link_weight(rel)
        self.adjacency.setdefault(from_state, {})[to_state] = (rel, weight)
        self.adjacency.setdefault(to_state, {})[from_state] = (inverse_rel(rel), weight)

    def add_traversal(self, from_state: int, to_state: int, rel: Rel) -> None:
        """Record that the robot drove ``rel`` from ``from_state`` to ``to_state``."""
        if from_state == to_state:
            return  # returning to the place it left: nothing new to link
        key = (min(from_state, to_state), max(from_state, to_state))
        link = self.links.get(key)
        if link is None:
            self.links[key] = LinkRecord(from_state, to_state, rel, 1)
        else:
            forward = rel if link.from_state == from_state else inverse_rel(rel)
            link.rel = fuse_rel(link.rel, forward)
            link.count += 1
        link = self.links[key]
        weight = link_weight(link.rel)
        self.adjacency.setdefault(link.from_state, {})[link.to_state] = (link.rel, weight)
        self.adjacency.setdefault(link.to_state, {})[link.from_state] = (inverse_rel(link.rel), weight)


class GrowableArray:
    """An append-only numpy array with amortised O(1) growth (observations, assignments)."""

    def __init__(self, row_shape: tuple[int, ...], dtype: np.dtype | type, capacity: int = 256) -> None:
        self._data = np.zeros((capacity, *row_shape), dtype=dtype)
        self._size = 0

    def append(self, row: npt.ArrayLike) -> int:
        if self._size == len(self._data):
            grown = np.zeros((2 * len(self._data), *self._data.shape[1:]), dtype=self._data.dtype)
            grown[: self._size] = self._data[: self._size]
            self._data = grown
        self._data[self._size] = row
        self._size += 1
        return self._size - 1

    def extend(self, rows: np.ndarray) -> None:
        for row in rows:
            self.append(row)

    def __len__(self) -> int:
        return self._size

    @property
    def view(self) -> np.ndarray:
        return self._data[: self._size]

    def take(self, rows: np.ndarray | int) -> np.ndarray:
        """``view[rows]`` without making the view first (a hot path): ``rows`` must be under ``len``."""
        return self._data[rows]


class KeyframeViews:
    """The view of every keyframe a hypothesis may still call a place; a place's view for good.

    A state is the keyframe of a place's first visit, so a keyframe's view is needed while some
    hypothesis may make it a new place. Once committed as a revisit it is no place in any
    hypothesis, and its row is reused: the views held grow with the places, not with the keyframes
    (the thumbnail's 768 bytes a keyframe were a long run's largest per-keyframe cost).
    """

    def __init__(self, length: int) -> None:
        self._rows = GrowableArray((length,), np.float32)
        self._row_of_keyframe = GrowableArray((), np.int64)
        self._free: list[int] = []

    def append(self, view: np.ndarray | None) -> int:
        """Store the next keyframe's view (None: a keyframe that is no place, as a prior map's
        revisits); returns its keyframe index."""
        if view is None:
            return self._row_of_keyframe.append(-1)
        if self._free:
            row = self._free.pop()
            self._rows.view[row] = view
        else:
            row = self._rows.append(view)
        return self._row_of_keyframe.append(row)

    def release(self, keyframe: int) -> None:
        """``keyframe`` was committed as a revisit: its view is never asked for again."""
        row = int(self._row_of_keyframe.view[keyframe])
        if row >= 0:
            self._row_of_keyframe.view[keyframe] = -1
            self._free.append(row)

    def __len__(self) -> int:
        return len(self._row_of_keyframe)

    def __getitem__(self, keyframes: int | np.ndarray) -> np.ndarray:
        """The views of ``keyframes`` (an index: one row; an array: one row each, a copy). On the
        SLAM step's path: the arrays are indexed directly, and a let-go keyframe (row -1) found by
        the minimum, with no temporaries."""
        rows = self._row_of_keyframe.view[keyframes]
        if rows.size and rows.min() < 0:
            raise KeyError(f"no view is kept of keyframe(s) {np.asarray(keyframes)[rows < 0].tolist()}")
        return self._rows.take(rows)

    @property
    def rows(self) -> int:
        """Views held (for tests: they follow the places)."""
        return len(self._rows) - len(self._free)
