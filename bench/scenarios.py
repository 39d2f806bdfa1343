"""Scenarios for ``make bench``: recordings (cached), and the real CLI run over each of them.

Every recording is made by ``aslam record`` and cached in ``bench/.cache/record-<hash>/``, where the
hash covers the recorder's and the recording format's source, so a change to either re-renders.
Every estimate is ``aslam estimate`` in a subprocess (its peak memory taken from ``wait4``), and
every score is ``aslam report --json -``: the figures are what a user gets.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "bench" / ".cache"
PAPER_LAP = 34
"""Actions per lap of the paper route: keyframe 34 is the start of the second lap."""


def aslam_command() -> list[str]:
    """The ``aslam`` console script of the interpreter running the bench."""
    script = Path(sys.executable).parent / "aslam"
    if script.exists():
        return [str(script)]
    found = shutil.which("aslam")
    if found is None:
        raise SystemExit("the aslam command is not installed next to this Python nor on PATH")
    return [found]


def source_hash() -> str:
    """Hash of everything that decides a recording's bytes: the recorder and the recording format."""
    digest = hashlib.sha256()
    files = [
        *sorted((ROOT / "recorder").glob("*.py")),
        ROOT / "data_formats" / "recording_writer.py",
        ROOT / "data_formats" / "images.py",
        ROOT / "data_formats" / "ros_msgs.py",
    ]
    for path in files:
        if path.exists():
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:10]


@dataclass(frozen=True)
class Scenario:
    family: str
    route: str
    laps: int
    seed: int
    noise: float = 0.03
    aliasing: float = 0.0
    fps: float | None = None
    size: str = "320x240"

    @property
    def name(self) -> str:
        parts = [self.route, f"laps{self.laps}", f"seed{self.seed}", f"noise{self.noise:g}"]
        if self.aliasing:
            parts.append(f"alias{self.aliasing:g}")
        if self.fps:
            parts.append(f"fps{self.fps:g}")
        parts.append(self.size)
        return "-".join(parts)

    @property
    def short_name(self) -> str:
        """A name short enough for a plot title."""
        name = f"{self.route}-seed{self.seed}"
        if self.laps != 2:
            name += f"-laps{self.laps}"
        if self.noise != 0.03:
            name += f"-noise{self.noise:g}"
        if self.aliasing:
            name += f"-aliasing{self.aliasing:g}"
        if self.fps:
            name += f"-fps{self.fps:g}"
        return name

    @property
    def second_lap_from(self) -> int | None:
        """First keyframe of the second lap (paper route driven twice or more), else None."""
        return PAPER_LAP if self.route == "paper" and self.laps >= 2 and not self.fps else None

    def record_args(self) -> list[str]:
        args = ["--route", self.route, "--laps", str(self.laps), "--seed", str(self.seed)]
        args += ["--noise", f"{self.noise:g}", "--size", self.size]
        if self.aliasing:
            args += ["--aliasing", f"{self.aliasing:g}"]
        if self.fps:
            args += ["--fps", f"{self.fps:g}"]
        return args

    def command(self) -> str:
        return "aslam record " + " ".join(self.record_args()) + " -o REC.mcap"


def cache_dir() -> Path:
    folder = CACHE / f"record-{source_hash()}"
    if not folder.exists():
        CACHE.mkdir(exist_ok=True)
        for stale in CACHE.glob("record-*"):
            shutil.rmtree(stale, ignore_errors=True)
        folder.mkdir()
    return folder


def recording(scenario: Scenario, log=print) -> tuple[Path, float | None]:
    """The cached recording of ``scenario`` (rendered now if missing) and the seconds it took, if rendered."""
    path = cache_dir() / f"{scenario.name}.mcap"
    if path.exists():
        return path, None
    log(f"  recording {path.name} ...")
    start = time.perf_counter()
    run([*aslam_command(), "record", *scenario.record_args(), "-o", str(path)])
    return path, time.perf_counter() - start


def run(command: list[str]) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({result.returncode}):\n{result.stderr[-3000:]}")
    return result


def run_measured(command: list[str]) -> tuple[str, float, float]:
    """Run ``command``; its stdout, wall seconds and peak RSS in MiB (itself and its waited-for children)."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as out_file, tempfile.TemporaryFile() as err_file:
        process = subprocess.Popen(command, stdout=out_file, stderr=err_file, stdin=subprocess.DEVNULL)
        # Not process.wait(): wait4 also gives the child's resource usage (its peak RSS and that of
        # the children it waited for, such as the estimate's forked reader).
        _, status, usage = os.wait4(process.pid, 0)
        process.returncode = os.waitstatus_to_exitcode(status)
        out_file.seek(0)
        err_file.seek(0)
        out, err = out_file.read(), err_file.read()
    wall = time.perf_counter() - start
    if process.returncode != 0:
        text = err.decode(errors="replace")[-3000:]
        raise SystemExit(f"{' '.join(command)} failed ({process.returncode}):\n{text}")
    rss_mib = usage.ru_maxrss / 1024 if sys.platform != "darwin" else usage.ru_maxrss / 2**20
    return out.decode(), wall, rss_mib


ESTIMATORS = {
    "aslam": [],
    "paper-faithful": ["--paper-faithful"],
}
"""The estimator settings compared: the project's defaults and ``--paper-faithful``."""


def estimate_and_report(
    recording_path: Path, estimate_path: Path, scenario: Scenario, estimator: str, plots: Path | None = None
) -> dict[str, Any]:
    """``aslam estimate`` then ``aslam report --json -``: the summary JSON plus wall time and peak RSS."""
    args = [*ESTIMATORS[estimator], "--odometry-noise", f"{scenario.noise:g}"]
    _, wall, rss = run_measured(
        [*aslam_command(), "estimate", str(recording_path), "-o", str(estimate_path), "--force", *args]
    )
    report = [*aslam_command(), "report", str(estimate_path), "--json", "-"]
    if plots is not None:
        report += ["--plots", str(plots)]
    summary = json.loads(run(report).stdout)
    return {"summary": summary, "wall_s": wall, "peak_rss_mib": rss, "estimate_args": args}


def estimate_steps(estimate_path: Path) -> list[tuple[int, tuple[Any, ...]]]:
    """(keyframe, hypotheses best first) of every keyframe of an estimate file."""
    from contextlib import closing

    from aslam.data_formats.estimate import iter_keyframes

    with closing(iter_keyframes(estimate_path)) as keyframes:
        return [(k.index, k.hypotheses) for k in keyframes]
