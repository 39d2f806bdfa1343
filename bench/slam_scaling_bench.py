"""Per-keyframe SLAM time against map size, on a long synthetic walk (no images).

Two synthetic worlds (1 m steps, 90° turns, 3 % odometry noise; each place-and-heading has its
own random observation — a histogram or a thumbnail-like vector, as the default model needs —
each view a noisy copy): ``blocks`` drives twice round each city block and
moves on, so the map grows for ever at constant density; ``random`` wanders a bounded grid, so
the map saturates and its links grow denser. Prints the mean per-keyframe time of ``add_keyframe`` over
the first and the last 1,000 keyframes and their ratio (target ≤ 1.2), plus peak memory. The first
1,000 are measured again alongside the last 1,000 (an identical run replayed in alternating blocks),
and that ratio is the one judged: the two windows of a long run are minutes apart. The replay goes
on through keyframes 1,000–2,000 too, for a second ratio that is not the target but tells growth
with the map from warm-up: in the first few hundred keyframes the map within the graph search's
reach is smaller than its budget, so the first window is cheaper by construction.

    python bench/slam_scaling_bench.py --keyframes 10000
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
import tracemalloc

import numpy as np

from aslam.core import se2
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator
from aslam.core.observation import HistogramModel, ThumbnailModel

WINDOW = 1000
"""Keyframes in each window of the ratio."""
BLOCK = 100
"""Keyframes of one run stepped before the other's, while the first window is replayed."""


def block_walk(keyframes: int, laps: int = 2, width: int = 6, height: int = 4):
    """Yield (true action, true pose): drive around a city block ``laps`` times, then move on to
    the next block along the street (sharing a corridor), forever.

    The map grows without bound while its local density stays the same: the run that shows
    whether the cost per keyframe depends on the number of states.
    """
    pose = np.zeros(3)
    forward, left = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, math.pi / 2])
    lap = ([forward] * width + [left] + [forward] * height + [left]) * 2
    produced = 1
    while True:
        for action in lap * laps + [forward] * width:  # then along the street to the next block
            pose = se2.compose(pose, action)
            yield action, pose
            produced += 1
            if produced >= keyframes:
                return


def random_walk(keyframes: int, size: int, seed: int):
    """Yield (true action, true pose) for a random walk on a size×size grid of 1 m cells.

    The map saturates at the grid's place count while it grows denser in links: a harder case.
    """
    rng = np.random.default_rng(seed)
    pose = np.zeros(3)
    for _ in range(keyframes - 1):
        ahead = se2.compose(pose, np.array([1.0, 0.0, 0.0]))
        blocked = not (0 <= round(ahead[0]) < size and 0 <= round(ahead[1]) < size)
        if blocked or rng.random() < 0.2:
            action = np.array([0.0, 0.0, math.pi / 2 * rng.choice([-1.0, 1.0])])
        else:
            action = np.array([1.0, 0.0, 0.0])
        pose = se2.compose(pose, action)
        yield action, pose


class Run:
    """One synthetic run, stepped one keyframe at a time: the walk, its noisy odometry and views,
    and the estimator. Two runs made with the same arguments are identical, keyframe for keyframe."""

    def __init__(self, keyframes: int, world: str, size: int, seed: int) -> None:
        self._rng = np.random.default_rng(seed + 1)
        config = EstimatorConfig()
        self.estimator = Estimator(config)
        model = self.estimator.observation_model
        self._length = model.length
        self._histogram = isinstance(model, HistogramModel)
        # A query is compared at each of its phases (``thumbnail_phases``): as many noisy copies.
        self._phases = model.phases if isinstance(model, ThumbnailModel) else 1
        self._signatures: dict[tuple[int, int, int], np.ndarray] = {}
        self._walk = block_walk(keyframes) if world == "blocks" else random_walk(keyframes, size, seed)
        self.keyframe = 0
        self.estimator.add_keyframe(0, np.zeros(3), self._observe(np.zeros(3)))

    def _observe(self, pose: np.ndarray) -> np.ndarray:
        """A histogram (noisy copy of the place's) or a thumbnail-like vector (the place's plus noise,
        one copy per phase)."""
        key = (round(pose[0]), round(pose[1]), round(math.degrees(pose[2]) / 90) % 4)
        length, rng = self._length, self._rng
        if key not in self._signatures:
            self._signatures[key] = (
                rng.dirichlet(np.full(length, 2.0)) if self._histogram else rng.standard_normal(length)
            )
        if not self._histogram:
            noise = 0.3 * rng.standard_normal((self._phases, length))
            return (self._signatures[key] + noise).astype(np.float32).ravel()
        view = np.abs(self._signatures[key] * (1.0 + 0.05 * rng.standard_normal(length)))
        return (view / view.sum()).astype(np.float32)

    def step(self) -> tuple[float, int]:
        """The next keyframe: seconds ``add_keyframe`` took, and the hypotheses after it."""
        action, pose = next(self._walk)
        self.keyframe += 1
        noisy = action * (1.0 + 0.03 * self._rng.standard_normal(3))
        z = self._observe(pose)
        t0 = time.perf_counter()
        result = self.estimator.add_keyframe(self.keyframe, noisy, z)
        return time.perf_counter() - t0, len(result.hypotheses)


def run(keyframes: int, world: str, size: int, seed: int, trace_memory: bool) -> dict:
    """The run's cost per keyframe over its first and last ``WINDOW`` keyframes.

    The first window is measured twice: at the start of the run, and again alongside the last one
    (an identical fresh run, its first keyframes stepped in blocks of ``BLOCK`` alternating with
    the long run's last ones), so that both windows of the judged ratio see the same machine: the
    windows of a long run are minutes apart, and the machine's speed drifts by more than the target
    in that time. When the run is long enough, the replay steps two blocks per block and so also
    measures the second window (keyframes ``WINDOW``–2 × ``WINDOW``) alongside the last.
    """
    if trace_memory:
        tracemalloc.start()
    window = min(WINDOW, keyframes // 2)
    main_run = Run(keyframes, world, size, seed)
    times = np.zeros(keyframes)
    hypotheses = np.ones(keyframes, dtype=np.int64)
    start = time.perf_counter()
    replay: Run | None = None
    replay_times: list[float] = []
    replayed = 2 * window if keyframes >= 4 * window else window  # keyframes of the replay
    for k in range(1, keyframes):
        if k == keyframes - window:
            replay = Run(keyframes, world, size, seed)
        times[k], hypotheses[k] = main_run.step()
        if replay is not None and (k - (keyframes - window)) % BLOCK == BLOCK - 1:
            replay_times += [replay.step()[0] for _ in range(BLOCK * replayed // window)]
        if k % 1000 == 0:
            print(f"  {k} keyframes, {(time.perf_counter() - start):.1f} s", file=sys.stderr)
    if replay is not None:
        replay_times += [replay.step()[0] for _ in range(replayed - len(replay_times))]
    traced_peak = tracemalloc.get_traced_memory()[1] if trace_memory else None
    stats = main_run.estimator.result().stats
    at_start, last = times[1 : window + 1].mean(), times[-window:].mean()
    first = float(np.mean(replay_times[:window])) if replay_times else at_start
    second = float(np.mean(replay_times[window:])) if len(replay_times) > window else None
    return {
        "world": world,
        "keyframes": keyframes,
        "window": window,
        "states": len(main_run.estimator.result().states),
        "first_ms": first * 1e3,
        "first_ms_at_start": at_start * 1e3,
        "last_ms": last * 1e3,
        "ratio_last_over_first": last / first,
        "ratio_at_start": last / at_start,
        "second_ms": None if second is None else second * 1e3,
        "ratio_last_over_second": None if second is None else last / second,
        "hypotheses_mean": float(hypotheses.mean()),
        "hypotheses_max": int(hypotheses.max()),
        "searched_states_mean": stats.searched_states_mean,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "traced_peak_mib": None if traced_peak is None else traced_peak / 2**20,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keyframes", type=int, default=10_000)
    parser.add_argument("--world", choices=["blocks", "random"], default="blocks")
    parser.add_argument("--size", type=int, default=20, help="random world: grid side in metres")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trace-memory", action="store_true", help="also trace Python allocations (slower)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = run(args.keyframes, args.world, args.size, args.seed, args.trace_memory)
    if args.json:
        print(json.dumps(result))
        return
    print(f"world                {result['world']}")
    print(f"keyframes            {result['keyframes']}")
    print(f"states in final map  {result['states']}")
    print(
        f"first {result['window']}: {result['first_ms']:.3f} ms/keyframe   "
        f"last {result['window']}: {result['last_ms']:.3f} ms/keyframe"
    )
    print(f"ratio last/first     {result['ratio_last_over_first']:.2f}   (target <= 1.2)")
    if result["second_ms"] is not None:
        print(
            f"second {result['window']}: {result['second_ms']:.3f} ms/keyframe   ratio last/second "
            f"{result['ratio_last_over_second']:.2f}   (past the search's warm-up; not the target)"
        )
    print(f"hypotheses mean/max  {result['hypotheses_mean']:.2f} / {result['hypotheses_max']}")
    print(f"states searched per keyframe (all hypotheses)  {result['searched_states_mean']:.1f}")
    print(f"peak RSS             {result['peak_rss_mib']:.0f} MiB")


if __name__ == "__main__":
    main()
