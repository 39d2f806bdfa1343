"""Per-keyframe SLAM time against map size, on a long synthetic walk (no images).

Two synthetic worlds (1 m steps, 90° turns, 3 % odometry noise; each place-and-heading has its
own random observation — a histogram or a thumbnail-like vector, as the default model needs —
each view a noisy copy): ``blocks`` drives twice round each city block and
moves on, so the map grows for ever at constant density; ``random`` wanders a bounded grid, so
the map saturates and its links grow denser. Prints the mean per-keyframe time of ``add_keyframe`` over
the first and the last 1,000 keyframes and their ratio (target ≤ 1.2), measured in one run,
plus peak memory.

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
from aslam.core.observation import HistogramModel


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


def run(keyframes: int, world: str, size: int, seed: int, trace_memory: bool) -> dict:
    rng = np.random.default_rng(seed + 1)
    config = EstimatorConfig()
    model = Estimator(config).observation_model
    length = model.length
    histogram = isinstance(model, HistogramModel)
    signatures: dict[tuple[int, int, int], np.ndarray] = {}

    def observe(pose: np.ndarray) -> np.ndarray:
        """A histogram (noisy copy of the place's) or a thumbnail-like vector (the place's plus noise)."""
        key = (round(pose[0]), round(pose[1]), round(math.degrees(pose[2]) / 90) % 4)
        if key not in signatures:
            signatures[key] = (
                rng.dirichlet(np.full(length, 2.0)) if histogram else rng.standard_normal(length)
            )
        if not histogram:
            return (signatures[key] + 0.3 * rng.standard_normal(length)).astype(np.float32)
        view = np.abs(signatures[key] * (1.0 + 0.05 * rng.standard_normal(length)))
        return (view / view.sum()).astype(np.float32)

    if trace_memory:
        tracemalloc.start()
    estimator = Estimator(config)
    times = np.zeros(keyframes)
    hypotheses = np.zeros(keyframes, dtype=np.int64)
    start = time.perf_counter()
    times[0] = 0.0
    estimator.add_keyframe(0, np.zeros(3), observe(np.zeros(3)))
    walk = block_walk(keyframes) if world == "blocks" else random_walk(keyframes, size, seed)
    for k, (action, pose) in enumerate(walk, start=1):
        noisy = action * (1.0 + 0.03 * rng.standard_normal(3))
        z = observe(pose)
        t0 = time.perf_counter()
        result = estimator.add_keyframe(k, noisy, z)
        times[k] = time.perf_counter() - t0
        hypotheses[k] = len(result.hypotheses)
        if k % 1000 == 0:
            print(f"  {k} keyframes, {(time.perf_counter() - start):.1f} s", file=sys.stderr)
    traced_peak = tracemalloc.get_traced_memory()[1] if trace_memory else None
    stats = estimator.result().stats
    window = min(1000, keyframes // 2)
    first, last = times[1 : window + 1].mean(), times[-window:].mean()
    return {
        "world": world,
        "keyframes": keyframes,
        "states": len(estimator.result().states),
        "first_ms": first * 1e3,
        "last_ms": last * 1e3,
        "ratio_last_over_first": last / first,
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
        f"first 1000: {result['first_ms']:.3f} ms/keyframe   last 1000: {result['last_ms']:.3f} ms/keyframe"
    )
    print(f"ratio last/first     {result['ratio_last_over_first']:.2f}   (target <= 1.2)")
    print(f"hypotheses mean/max  {result['hypotheses_mean']:.2f} / {result['hypotheses_max']}")
    print(f"states searched per keyframe (all hypotheses)  {result['searched_states_mean']:.1f}")
    print(f"peak RSS             {result['peak_rss_mib']:.0f} MiB")


if __name__ == "__main__":
    main()
