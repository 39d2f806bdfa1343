"""Multi-session maps on rendered worlds: a map from one run, a second run of the same world under
other conditions estimated in it (``estimate --map``), scored against both runs' ground truth.

The map is the default recording of a route and seed; each second session is the same route and
seed under one of the robust-revisit families (other light, off-pose revisits, a wandering path, a
video-rate stream, noisier odometry: ``bench/robust_matrix.py``'s recordings, rendered once and
cached). Every keyframe of a second session revisits the map, so recall counts all of them.

    python bench/multi_session.py [--routes paper figure8 grid] [--seeds 1 2 3] [--cache /tmp/robust/rec]
        [--json bench/results/multi_session.json]

Prints one row per session and a markdown table of the per-family means and worst cases.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from robust_matrix import ROUTES, Scenario, recording

from aslam.app.estimate import estimate
from aslam.app.score import score
from aslam.core.config import EstimatorConfig

SESSIONS = ("lighting50", "jitter15", "wander30", "fps5", "noise5")


def run(route: str, seed: int, family: str, cache: Path, workdir: Path) -> dict:
    config = EstimatorConfig()
    the_map = workdir / f"map-{route}-{seed}.est.mcap"
    if not the_map.exists():
        estimate(recording(Scenario("default", route, seed), cache), the_map, config, timing=False)
    session = Scenario(family, route, seed)
    out = workdir / f"{session.name}.est.mcap"
    estimate(recording(session, cache), out, config, timing=False, prior=the_map)
    summary = score(out).summary
    closure = summary["loop_closure"]
    return {
        "route": route,
        "seed": seed,
        "family": family,
        "map": Scenario("default", route, seed).command(),
        "session": session.command(),
        "keyframes": summary["keyframes"],
        "claims": closure["claims"],
        "precision": closure["precision"],
        "recall": closure["recall"],
        "first_delay": summary["relocalisation"]["first_delay_keyframes"],
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| session (in the default run's map) | runs | precision mean (min) | recall mean (min)"
        " | first delay max |",
        "|---|---|---|---|---|",
    ]
    for family in SESSIONS:
        mine = [r for r in rows if r["family"] == family]
        if not mine:
            continue
        precision = [r["precision"] if r["precision"] is not None else 0.0 for r in mine]
        recall = [r["recall"] or 0.0 for r in mine]
        delays = [r["first_delay"] for r in mine]
        worst = "never" if any(d is None for d in delays) else str(max(delays))
        lines.append(
            f"| {family} | {len(mine)} | {sum(precision) / len(mine):.3f} ({min(precision):.3f}) | "
            f"{sum(recall) / len(mine):.3f} ({min(recall):.3f}) | {worst} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--routes", nargs="+", default=list(ROUTES), choices=ROUTES)
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--families", nargs="+", default=list(SESSIONS), choices=SESSIONS)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/robust/rec"))
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="aslam-sessions-") as folder:
        for route in args.routes:
            for seed in args.seeds:
                for family in args.families:
                    row = run(route, seed, family, args.cache, Path(folder))
                    rows.append(row)
                    print(
                        f"{family:>10} {route:>7} seed {seed}: {row['claims']}/{row['keyframes']} claimed,"
                        f" precision {row['precision']}, recall {row['recall'] or 0:.3f},"
                        f" delay {row['first_delay']}",
                        flush=True,
                    )
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "table": table(rows)}, indent=1) + "\n")


if __name__ == "__main__":
    main()
