"""Fuzz the command line with hostile inputs and check the error contract on every one.

    python tests/fuzz.py N [--seed S] [--subprocess-every K] [--json FILE]

Four kinds of input, in turn: damaged recordings (byte flips, truncation, spliced bytes and
hostile values in an uncompressed copy of a real small recording) through ``info`` and
``estimate``; damaged estimate files (JSON messages mutated at a random place, or bytes flipped)
through ``report``; damaged route files through ``record``; hostile option values through
``estimate``, ``report`` and ``record``. Output names are drawn too: fresh names, the input itself,
``sub/../input``, a symlink to the input, ``/dev/null``, an existing file without ``--force``.

Every case runs ``aslam.cli.app.main([...])`` in this process with stdout and stderr captured;
one in K runs as a real ``aslam`` subprocess (which also shows anything C libraries print). Each
case must: exit 0 or 2; print nothing on stderr on success (``-q``) and exactly one line
``aslam: error: …`` on failure; never print a traceback; leave every input byte-identical; and
after a failure leave nothing under any output name and no temporary file. The summary (JSON on
stdout) has the counts, the exit-code histogram and the peak memory; docs/reliability.md has a run.

``tests/test_fuzz.py`` drives the same cases from hypothesis for a few seconds in CI.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import math
import os
import random
import resource
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

KINDS = ("recording", "estimate", "route", "options")
ASLAM = Path(sys.executable).with_name("aslam")

# --- seeds: a real small recording, its estimate, a route ---------------------------------------


def _view(i: int, rng: np.random.Generator) -> np.ndarray:
    """A 64×48 image that depends on the place (i mod 8), drawn without a renderer."""
    import cv2

    place = np.random.default_rng(i % 8)
    image = np.full((48, 64, 3), 40, np.uint8)
    for _ in range(8):
        p1 = tuple(int(v) for v in place.integers(0, 64, 2))
        p2 = tuple(int(v) for v in place.integers(0, 64, 2))
        colour = tuple(int(v) for v in place.integers(60, 255, 3))
        cv2.rectangle(image, p1, p2, colour, -1)
    return np.clip(image + rng.normal(0, 3, image.shape), 0, 255).astype(np.uint8)


def write_seed_recording(path: Path) -> None:
    """16 frames around a 2 m square (twice), PNG and JPEG images, odometry and ground truth."""
    from aslam.core import se2
    from aslam.data_formats.camera import CameraIntrinsics
    from aslam.data_formats.images import ImageFormat, encode_image
    from aslam.data_formats.recording_writer import RecordingWriter

    rng = np.random.default_rng(3)
    truth = np.zeros(3)
    poses = []
    for _lap in range(2):
        for _side in range(4):
            poses.append(truth.copy())
            truth = se2.compose(truth, np.array([1.0, 0.0, 0.0]))
            poses.append(truth.copy())
            truth = se2.compose(truth, np.array([1.0, 0.0, math.pi / 2]))
    with RecordingWriter(path, camera=CameraIntrinsics(64, 48, 60.0), metadata={"world": "fuzz"}) as writer:
        for i, pose in enumerate(poses):
            fmt = ImageFormat.JPEG if i % 5 == 4 else ImageFormat.PNG
            odometry = pose * (1 + 0.01 * rng.normal(size=3))
            writer.write(1_000_000_000 * (i + 1), encode_image(_view(i, rng), fmt), odometry, pose)


def write_plain_copy(source: Path, target: Path) -> None:
    """``source`` rewritten without compression or CRCs, so flipped bytes reach the messages."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with source.open("rb") as f, target.open("wb") as out:
        reader = make_reader(f)
        writer = Writer(out, compression=CompressionType.NONE, enable_crcs=False, chunk_size=16 * 1024)
        writer.start(profile="ros2", library="aslam fuzz")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, dict(record.metadata))
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(channel.schema_id, 0),
                    channel.metadata,
                )
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()


SEED_ROUTE = {"name": "fuzz", "start": {"x_m": 0, "y_m": 0, "yaw_deg": 0}, "actions": [
    {"forward_m": 1.0}, {"turn_deg": 90}, {"forward_m": 1.0},
]}  # fmt: skip


@dataclass
class Seeds:
    folder: Path
    recording: Path
    plain: Path
    estimate: Path
    route: Path
    estimate_messages: list[tuple[str, str, bytes, int]] = field(default_factory=list)


def make_seeds(folder: Path) -> Seeds:
    from aslam.cli.app import main

    folder.mkdir(parents=True, exist_ok=True)
    recording, plain = folder / "seed.mcap", folder / "seed-plain.mcap"
    estimate, route = folder / "seed-estimate.mcap", folder / "seed-route.json"
    write_seed_recording(recording)
    write_plain_copy(recording, plain)
    with contextlib.redirect_stderr(io.StringIO()):
        code = main(["estimate", str(plain), "-o", str(estimate), "--no-timing", "-q"])
    if code != 0:
        raise RuntimeError(f"the seed estimate failed with exit {code}")
    route.write_text(json.dumps(SEED_ROUTE))
    return Seeds(folder, recording, plain, estimate, route)


# --- mutations ----------------------------------------------------------------------------------

HOSTILE_NUMBERS = [
    "nan", "inf", "-inf", "-1", "0", "1e-308", "5e-324", "1e308", "1.7976931348623157e308", "1e200",
    "1e12", "100000", "-1e308", "2", "0.5", "1", "abc", "", "1e", "9" * 400, "0x10", "1_000",
]  # fmt: skip
HOSTILE_VALUES: list[Any] = [
    None, True, "x", -1, 0, 1e308, -1e308, 10**30, -(10**30), 1.5, [], {}, math.inf, -math.inf,
    math.nan, 2**63, [[1, 2, 3]], {"x_m": 1}, "Infinity", 1e-320,
]  # fmt: skip


def flip_bytes(data: bytes, rng: random.Random) -> bytes:
    """Damage ``data``: flipped bits, a truncation, spliced random bytes or a zeroed range."""
    out = bytearray(data)
    choice = rng.random()
    if choice < 0.5:
        for _ in range(rng.choice([1, 1, 2, 4, 16])):
            i = rng.randrange(len(out))
            out[i] ^= 1 << rng.randrange(8)
    elif choice < 0.7:
        return bytes(out[: rng.randrange(len(out))])
    elif choice < 0.85:
        i = rng.randrange(len(out))
        out[i : i + rng.randrange(1, 64)] = rng.randbytes(rng.randrange(1, 64))
    else:
        i = rng.randrange(len(out))
        n = rng.randrange(1, 256)
        out[i : i + n] = bytes(min(n, len(out) - i))
    return bytes(out)


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    found = [prefix]
    if isinstance(doc, dict):
        for key, value in doc.items():
            found += _paths(value, (*prefix, key))
    elif isinstance(doc, list):
        for i, value in enumerate(doc[:8]):
            found += _paths(value, (*prefix, i))
    return found


def mutated_json(doc: Any, rng: random.Random) -> str:
    """``doc`` as JSON text with one place deleted, replaced by a hostile value, or nested very deep."""
    doc = json.loads(json.dumps(doc))
    path = rng.choice(_paths(doc))
    op = rng.random()
    deep = rng.choice([10, 1000, 100_000])
    marker = '"__deep__"'
    if not path:
        doc = rng.choice(HOSTILE_VALUES) if op < 0.8 else "__deep__"
    else:
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        if op < 0.3:
            del parent[key]
        elif op < 0.95:
            parent[key] = rng.choice(HOSTILE_VALUES)
        else:
            parent[key] = "__deep__"
    return json.dumps(doc).replace(marker, "[" * deep + "1" + "]" * deep, 1)


def write_estimate_variant(seeds: Seeds, target: Path, rng: random.Random) -> None:
    """The seed estimate with one JSON message (keyframe or graph) or one metadata value mutated."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with seeds.estimate.open("rb") as f:
        reader = make_reader(f)
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    with seeds.estimate.open("rb") as f:
        messages = list(make_reader(f).iter_messages(log_time_order=True))
    # A JSON message of ours (the Foxglove scene is protobuf), or (len) the metadata instead.
    victim = rng.choice(
        [i for i, (_s, c, _m) in enumerate(messages) if c.message_encoding == "json"] + [len(messages)]
    )
    with target.open("wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="aslam fuzz")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for i, (name, record) in enumerate(metadata):
            if victim == len(messages) and i == 0 and record:
                key = rng.choice(sorted(record))
                record[key] = rng.choice(["", "x", "{}", "[]", "1e999", "-1", json.dumps(HOSTILE_VALUES)])
            writer.add_metadata(name, record)
        for i, (schema, channel, message) in enumerate(messages):
            if schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schema_ids[schema.id], channel.metadata
                )
            data = message.data
            if i == victim:
                data = mutated_json(json.loads(data), rng).encode()
            writer.add_message(channel_ids[channel.id], message.log_time, data, message.publish_time)
        writer.finish()


# --- cases --------------------------------------------------------------------------------------


@dataclass
class Case:
    """One command over hostile inputs, with what must survive it."""

    kind: str
    argv: list[str]
    inputs: list[Path]
    outputs: list[Path]
    folder: Path


def _output_name(folder: Path, input_path: Path, rng: random.Random, suffix: str) -> tuple[str, list[str]]:
    """An output argument, fresh or hostile, and the extra options it needs."""
    choice = rng.random()
    if choice < 0.75:
        return str(folder / f"out{suffix}"), []
    if choice < 0.82:
        return str(input_path), ["--force"]
    if choice < 0.88:
        (folder / "sub").mkdir(exist_ok=True)
        return str(folder / "sub" / ".." / input_path.name), ["--force"]
    if choice < 0.93:
        link = folder / f"link{suffix}"
        if not link.is_symlink():
            link.symlink_to(input_path)
        return str(link), ["--force"]
    if choice < 0.96:
        return "/dev/null", []
    existing = folder / f"existing{suffix}"
    existing.write_bytes(b"keep me")
    return str(existing), []


def recording_case(seeds: Seeds, folder: Path, rng: random.Random) -> Case:
    source = seeds.plain if rng.random() < 0.8 else seeds.recording
    path = folder / "rec.mcap"
    path.write_bytes(flip_bytes(source.read_bytes(), rng))
    if rng.random() < 0.5:
        return Case("recording", ["info", str(path), "-q", "--json", "-"], [path], [], folder)
    out, extra = _output_name(folder, path, rng, ".mcap")
    argv = ["estimate", str(path), "-o", out, "-q", "--no-timing", "--workers", "1", *extra]
    return Case("recording", argv, [path], [Path(out)], folder)


def estimate_case(seeds: Seeds, folder: Path, rng: random.Random) -> Case:
    path = folder / "est.mcap"
    if rng.random() < 0.7:
        write_estimate_variant(seeds, path, rng)
    else:
        path.write_bytes(flip_bytes(seeds.estimate.read_bytes(), rng))
    argv = ["report", str(path), "-q", "--recording", str(seeds.plain)]
    outputs: list[Path] = []
    for option, suffix in (("--json", ".json"), ("--graph", ".graph.json")):
        if rng.random() < 0.6:
            out, extra = _output_name(folder, path, rng, suffix)
            argv += [option, out, *extra]
            outputs.append(Path(out))
    return Case("estimate", argv, [path, seeds.plain], outputs, folder)


def route_case(seeds: Seeds, folder: Path, rng: random.Random) -> Case:
    path = folder / "route.json"
    if rng.random() < 0.6:
        text = mutated_json(SEED_ROUTE, rng)
    elif rng.random() < 0.5:
        text = flip_bytes(seeds.route.read_bytes(), rng).decode("latin-1")
    else:
        text = rng.choice(
            ["[" * 100_000 + "]" * 100_000, '{"actions": [' + '{"forward_m": 1},' * 200_000 + "]}"]
        )
    path.write_text(text, encoding="latin-1")
    out, extra = _output_name(folder, path, rng, ".mcap")
    argv = ["record", "--route", str(path), "-o", out, "-q", "--size", "32x24", "--laps", "1", *extra]
    outputs = [Path(out)]
    if rng.random() < 0.2:
        sheet, more = _output_name(folder, path, rng, ".png")
        argv += ["--contact-sheet", sheet, *more]
        outputs.append(Path(sheet))
    return Case("route", argv, [path], outputs, folder)


ESTIMATE_OPTIONS = [
    "--step-m", "--turn-deg", "--keyframe-slack", "--histogram-bins", "--cells-x", "--cells-y", "--beta",
    "--chi2-floor", "--new-state-chi2", "--odometry-noise", "--drift-deg-per-m", "--place-radius-m",
    "--place-heading-deg", "--visit-sigma-m", "--visit-sigma-deg", "--gate-sigma", "--revisit-prior",
    "--search-sigma-m", "--search-nearness", "--search-max-states", "--prune-ratio", "--max-hypotheses",
    "--merge-window", "--workers",
]  # fmt: skip
REPORT_OPTIONS = ["--radius-m", "--heading-deg"]


def options_case(seeds: Seeds, folder: Path, rng: random.Random) -> Case:
    choice = rng.random()
    if choice < 0.75:
        out = folder / "out.mcap"
        argv = ["estimate", str(seeds.plain), "-o", str(out), "-q", "--no-timing"]
        for option in rng.sample(ESTIMATE_OPTIONS, rng.choice([1, 1, 2, 3])):
            argv += [option, rng.choice(HOSTILE_NUMBERS)]
        return Case("options", argv, [seeds.plain], [out], folder)
    out = folder / "out.json"
    argv = ["report", str(seeds.estimate), "-q", "--recording", str(seeds.plain), "--json", str(out)]
    for option in rng.sample(REPORT_OPTIONS, rng.choice([1, 2])):
        argv += [option, rng.choice(HOSTILE_NUMBERS)]
    return Case("options", argv, [seeds.estimate, seeds.plain], [out], folder)


MAKERS = {
    "recording": recording_case,
    "estimate": estimate_case,
    "route": route_case,
    "options": options_case,
}


# --- running and checking -----------------------------------------------------------------------


@dataclass
class Outcome:
    kind: str
    argv: list[str]
    code: int
    stderr: str
    problems: list[str]
    seconds: float


def _digest(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None
    except OSError:
        return None


def _snapshot(case: Case) -> dict[Path, str | None]:
    return {p: _digest(p) for p in case.inputs}


def run_case(case: Case, *, subprocess_run: bool = False) -> Outcome:
    """Run ``case`` and list every way it broke the error contract (empty: it kept it)."""
    from aslam.cli.app import main

    before = _snapshot(case)
    existed = {p: (p.exists() or p.is_symlink()) for p in case.outputs}
    existing_content = {p: _digest(p) for p in case.outputs if existed[p]}
    start = time.perf_counter()
    if subprocess_run:
        done = subprocess.run([str(ASLAM), *case.argv], capture_output=True, text=True, timeout=600)
        code, stderr = done.returncode, done.stderr
    else:
        err, out = io.StringIO(), io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(case.argv)
        stderr = err.getvalue()
    seconds = time.perf_counter() - start
    problems = []
    lines = stderr.splitlines()
    if code not in (0, 2):
        problems.append(f"exit {code}")
    if "Traceback" in stderr:
        problems.append("traceback")
    if code == 0 and lines:
        problems.append(f"{len(lines)} stderr lines on success")
    if code != 0 and (len(lines) != 1 or not lines[0].startswith("aslam: error: ")):
        problems.append(f"{len(lines)} stderr lines on failure")
    for path, digest in before.items():
        if _digest(path) != digest:
            problems.append(f"input changed: {path.name}")
    if code != 0:
        for path in case.outputs:
            if str(path) == "/dev/null":
                continue
            if existed[path]:
                if _digest(path) != existing_content[path]:
                    problems.append(f"existing output replaced by a failed run: {path.name}")
            elif path.exists():
                problems.append(f"output left after failure: {path.name}")
    leftovers = [p.name for p in case.folder.rglob("*.partial-*")]
    if leftovers:
        problems.append(f"temporary files left: {leftovers}")
    if not Path("/dev/null").is_char_device():
        problems.append("/dev/null is no longer a device")
    return Outcome(case.kind, case.argv, code, stderr, problems, seconds)


def peak_rss_mib() -> dict[str, float]:
    """Peak resident memory of this process and of its largest finished child (readers, subprocesses)."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return {"this_process_mib": round(own, 1), "largest_child_mib": round(children, 1)}


def fuzz(n: int, *, seed: int = 0, subprocess_every: int = 50, log: Any = None) -> dict[str, Any]:
    """Run ``n`` cases, the kinds in turn; the summary of what happened."""
    rng = random.Random(seed)
    codes: Counter[str] = Counter()
    per_kind: dict[str, Counter[str]] = {kind: Counter() for kind in KINDS}
    failures: list[dict[str, Any]] = []
    seconds: Counter[str] = Counter()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="aslam-fuzz-") as tmp:
        seeds = make_seeds(Path(tmp) / "seeds")
        for i in range(n):
            kind = KINDS[i % len(KINDS)]
            folder = Path(tmp) / f"case-{i}"
            folder.mkdir()
            case = MAKERS[kind](seeds, folder, rng)
            as_subprocess = subprocess_every > 0 and rng.randrange(subprocess_every) == 0
            outcome = run_case(case, subprocess_run=as_subprocess)
            if not as_subprocess and outcome.code in (130, 143):
                raise KeyboardInterrupt  # the signal was meant for this run, not for the case
            codes[str(outcome.code)] += 1
            per_kind[kind][str(outcome.code)] += 1
            per_kind[kind]["subprocess" if as_subprocess else "in_process"] += 1
            seconds[kind] += outcome.seconds
            if outcome.problems:
                failures.append({"argv": outcome.argv, "code": outcome.code, "problems": outcome.problems,
                                 "stderr": outcome.stderr[-2000:]})  # fmt: skip
                if log is not None:
                    print(json.dumps(failures[-1]), file=log, flush=True)
            for child in sorted(folder.rglob("*"), reverse=True):
                child.unlink() if not child.is_dir() or child.is_symlink() else child.rmdir()
            folder.rmdir()
            if log is not None and (i + 1) % 200 == 0:
                print(f"{i + 1}/{n} cases, {len(failures)} failures, {time.perf_counter() - started:.0f} s",
                      file=log, flush=True)  # fmt: skip
    problems: Counter[str] = Counter(p.split(":")[0] for f in failures for p in f["problems"])
    return {
        "cases": n,
        "seed": seed,
        "exit_codes": dict(sorted(codes.items())),
        "per_kind": {kind: dict(sorted(c.items())) for kind, c in per_kind.items()},
        "seconds_per_kind": {kind: round(s, 1) for kind, s in seconds.items()},
        "cases_breaking_the_contract": len(failures),
        "problems": dict(problems),
        "exit_70": codes.get("70", 0),
        "failures": failures[:50],
        "peak_memory": peak_rss_mib(),
        "wall_s": round(time.perf_counter() - started, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cases", type=int, help="Number of cases (spread evenly over the four kinds).")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--subprocess-every", type=int, default=50, help="One case in K as a real subprocess."
    )
    parser.add_argument("--json", type=Path, help="Also write the summary here.")
    args = parser.parse_args()
    # C libraries print to descriptor 2 in this process (the console script silences them itself);
    # the log keeps the real stderr.
    log = os.fdopen(os.dup(2), "w", buffering=1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    summary = fuzz(args.cases, seed=args.seed, subprocess_every=args.subprocess_every, log=log)
    text = json.dumps(summary, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0 if summary["cases_breaking_the_contract"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
