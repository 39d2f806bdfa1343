"""Kidnaps and odometry resets as the recorder makes them, scored: relocalised how soon, wrong how often.

``bench/robust_matrix.py``'s ``kidnap`` and ``reset`` families are made from its default renders
(frames dropped, odometry restarted), so the event is the only change from the run beside them.
This bench makes them as a user would: a route driven twice with a ``kidnap`` action three
quarters of the way (``routes.kidnapped``: carried back to the commanded pose 30 % of the way,
in the first lap, and driven on from there), and ``aslam record --odometry-reset-at K`` at 70 % of
the keyframes (``--lighting-change`` and ``--fps`` as ``aslam record``'s). Each recording is
estimated with the defaults and scored through the application layer; the event is the first
keyframe whose odometry disagrees with the true motion by over 1 m or 45°, as the matrix finds its own.

    python bench/recorder_events.py --routes paper figure8 grid bench/routes/hexagon.json \
        --seeds 96 97 --markdown bench/results/recorder_events.md --json bench/results/recorder_events.json

Prints one JSON line per run, then the table.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from aslam.app.estimate import estimate
from aslam.app.score import score
from aslam.core.config import EstimatorConfig
from aslam.recorder import routes
from aslam.recorder.config import RecordConfig
from aslam.recorder.record import record

sys.path.insert(0, str(Path(__file__).resolve().parent))
from robust_matrix import event_keyframe

KIDNAP_AT, KIDNAP_TO, RESET_AT = 0.75, 0.3, 0.7
"""Shares of a twice-driven route's keyframes: carried at the first to the second; reset at the third."""
KINDS = ("kidnap", "reset")


def recording(route_spec: str, seed: int, kind: str, folder: Path, knobs: dict[str, float]) -> Path:
    """The rendered recording; ``knobs``: other RecordConfig settings (``lighting_change``, ``fps``)."""
    twice = routes.resolve_route(route_spec).repeated(2)
    count = len(twice.actions)
    tag = "".join(f"-{name.replace('_', '')}{value:g}" for name, value in sorted(knobs.items()))
    path = folder / f"{Path(route_spec).stem}-seed{seed}{tag}-{kind}.mcap"
    route_file = path.with_suffix(".json")
    if kind == "kidnap":
        route = routes.kidnapped(twice, int(KIDNAP_AT * count), int(KIDNAP_TO * count))
        event: dict[str, Any] = {}
    else:
        route = twice
        event = {"odometry_reset_at": int(RESET_AT * count)}
    route_file.write_text(route.to_json())
    if not path.exists():
        record(RecordConfig(route=str(route_file), laps=1, seed=seed, **knobs, **event), path)
    return path


def run(route_spec: str, seed: int, kind: str, folder: Path, knobs: dict[str, float]) -> dict[str, Any]:
    """The event is found as the matrix finds its own (``robust_matrix.event_keyframe``): the first
    keyframe whose odometry disagrees with the true motion by over 1 m or 45°."""
    rec = recording(route_spec, seed, kind, folder, knobs)
    out = rec.with_suffix(".estimate.mcap")
    estimate(rec, out, EstimatorConfig(), timing=False, force=True)
    report = score(out, recording=rec)
    evaluation = report.evaluation
    event = event_keyframe(report.actions, report.true_poses)
    assert event is not None, f"{rec}: no keyframe's odometry disagrees with the truth"
    right_after = np.flatnonzero(evaluation.correct[event:])
    closure = report.summary["loop_closure"]
    return {
        "run": rec.stem,
        "kind": kind,
        "precision": closure["precision"],
        "recall": closure["recall"],
        "event_keyframe": event,
        "relocalised_after": int(right_after[0]) if len(right_after) else None,
        "wrong_claims": int(evaluation.wrong.sum()),
        "wrong_claims_after_event": int(evaluation.wrong[event:].sum()),
    }


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| event | runs | precision min | recall mean (min) | relocalised after (keyframes), max | never"
        " | wrong claims (after the event) |",
        "|---|---|---|---|---|---|---|",
    ]
    for kind in KINDS:
        group = [r for r in rows if r["kind"] == kind]
        if not group:
            continue
        recalls = [r["recall"] for r in group]
        delays = [r["relocalised_after"] for r in group if r["relocalised_after"] is not None]
        lines.append(
            f"| {kind} | {len(group)} | {min(r['precision'] for r in group):.3f}"
            f" | {np.mean(recalls):.3f} ({min(recalls):.2f}) | {max(delays) if delays else '—'}"
            f" | {len(group) - len(delays)} | {sum(r['wrong_claims'] for r in group)}"
            f" ({sum(r['wrong_claims_after_event'] for r in group)}) |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--routes", nargs="+", default=["paper", "figure8", "grid"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--lighting-change", type=float, default=0.0, help="as aslam record's")
    parser.add_argument("--fps", type=float, help="as aslam record's (images per action)")
    parser.add_argument("--cache", type=Path, help="keep the recordings here (default: a temporary folder)")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    knobs = {"lighting_change": args.lighting_change} if args.lighting_change else {}
    if args.fps is not None:
        knobs["fps"] = args.fps
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.cache or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        for route_spec in args.routes:
            for seed in args.seeds:
                for kind in args.kinds:
                    rows.append(run(route_spec, seed, kind, folder, knobs))
                    print(json.dumps(rows[-1]), flush=True)
    text = table(rows)
    sys.stdout.write(text)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()
