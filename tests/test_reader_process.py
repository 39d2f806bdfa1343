"""The estimate's reader process: started when ``run_estimate`` is called, so the caller's set-up
overlaps the reading; the same steps as reading in-process; stopped by ``close()`` whenever it comes."""

from __future__ import annotations

import array
import fcntl
import multiprocessing
import os
import termios
import threading
import time
from pathlib import Path

import pytest
from conftest import long_recording, write_square_recording, write_with_corrupt_image

from aslam.app.pipeline import PIPE_BYTES, can_fork, run_estimate
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import ImageFormat
from aslam.data_formats.recording import Recording

DEFAULT_PIPE_BYTES = 64 * 1024  # Linux's


def readers() -> list[str]:
    return [p.name for p in multiprocessing.active_children() if p.name == "aslam-reader"]


pytestmark = pytest.mark.skipif(not can_fork(), reason="the reader process needs fork")


def steps_of(path: Path, *, reader_process: bool) -> list[tuple[int, tuple[int, ...]]]:
    steps = run_estimate(
        Recording(path).samples(), Estimator(EstimatorConfig()), reader_process=reader_process
    )
    try:
        return [(step.keyframe, tuple(h.state for h in step.hypotheses)) for step in steps]
    finally:
        steps.close()


@pytest.fixture(scope="module")
def square(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("reader") / "square.mcap"
    write_square_recording(path)
    return path


def test_the_reader_process_gives_the_steps_of_reading_in_process(square):
    in_child = steps_of(square, reader_process=True)
    assert in_child == steps_of(square, reader_process=False)
    assert len(in_child) > 10


@pytest.fixture(scope="module")
def long(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1,500 keyframes, far more than the pipe holds: the reader cannot finish while unread."""
    path = tmp_path_factory.mktemp("reader") / "long.mcap"
    long_recording(path, frames=1500)
    return path


def closed_unfinished(steps) -> None:
    """``steps.close()``, which must stop a reader that is still reading (blocked on the full pipe)
    rather than wait for it to finish: waiting would never end."""
    closing = threading.Thread(target=steps.close, daemon=True)
    closing.start()
    closing.join(timeout=60)
    assert not closing.is_alive(), "close() waited for a reader that cannot finish"
    assert readers() == []


def test_the_reader_starts_at_once_and_close_stops_it_unread(long):
    steps = run_estimate(Recording(long).samples(), Estimator(EstimatorConfig()))
    assert readers() == ["aslam-reader"]
    closed_unfinished(steps)


def pipe_max_size() -> int:
    """What the kernel lets an unprivileged process give a pipe (0 where it does not say)."""
    try:
        return int(Path("/proc/sys/fs/pipe-max-size").read_text())
    except (OSError, ValueError):
        return 0


@pytest.mark.skipif(
    not hasattr(fcntl, "F_SETPIPE_SZ") or pipe_max_size() < PIPE_BYTES,
    reason="pipe sizes are Linux's, up to /proc/sys/fs/pipe-max-size",
)
def test_the_reader_runs_ahead_of_a_parent_busy_elsewhere(long):
    """The parent imports GTSAM while the reader starts: the reader must not stop at the 64 KiB of a
    default pipe (some 20 frames) and wait for it. Unread, it fills PIPE_BYTES."""
    steps = run_estimate(Recording(long).samples(), Estimator(EstimatorConfig()))
    receiver = steps._reader._receiver  # type: ignore[union-attr]
    waiting = array.array("i", [0])
    deadline = time.monotonic() + 60
    while waiting[0] <= 4 * DEFAULT_PIPE_BYTES and time.monotonic() < deadline:
        fcntl.ioctl(receiver.fileno(), termios.FIONREAD, waiting)
        time.sleep(0.05)
    try:
        assert waiting[0] > 4 * DEFAULT_PIPE_BYTES
        assert waiting[0] <= PIPE_BYTES
    finally:
        closed_unfinished(steps)


def test_close_after_some_steps_stops_the_reader(long):
    steps = run_estimate(Recording(long).samples(), Estimator(EstimatorConfig()))
    first = next(iter(steps))
    assert first.keyframe == 0
    closed_unfinished(steps)


def describing_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("aslam-describe")]


@pytest.mark.parametrize("reader_process", [True, False])
def test_leaving_the_loop_of_steps_early_stops_the_reader(long, reader_process):
    """A notebook's ``for step in steps: ... break`` (or ``iter(steps).close()``) never calls
    ``steps.close()``: the reader (a child blocked on its full pipe, or the describing threads in
    this process) must stop when the loop is left, not when ``steps`` is collected."""
    steps = run_estimate(
        Recording(long).samples(), Estimator(EstimatorConfig()), reader_process=reader_process
    )
    for step in steps:
        if step.keyframe == 2:
            break
    assert readers() == []
    assert describing_threads() == []
    del steps


def _estimate_in_a_daemon(recording: Path, output: Path, answers) -> None:
    from aslam.app.estimate import estimate

    try:
        answers.put(estimate(recording, output, EstimatorConfig(), timing=False).keyframes)
    except BaseException as err:
        answers.put(f"{type(err).__name__}: {err}")


def test_estimate_with_its_defaults_runs_in_a_daemonic_process(square, tmp_path):
    """A researcher's own Dask task (its worker a daemonic process, as a ``multiprocessing`` pool's)
    calling ``estimate()`` with its defaults: the reader cannot be a child there, so it reads in
    that process, with the same bytes; it was ``AssertionError: daemonic processes are not allowed
    to have children``."""
    from aslam.app.estimate import estimate

    context = multiprocessing.get_context("spawn")
    answers = context.Queue()
    daemon = context.Process(
        target=_estimate_in_a_daemon, args=(square, tmp_path / "daemon.mcap", answers), daemon=True
    )
    daemon.start()
    keyframes = answers.get(timeout=120)
    daemon.join()
    assert isinstance(keyframes, int) and keyframes > 10, keyframes
    estimate(square, tmp_path / "here.mcap", EstimatorConfig(), timing=False)
    assert (tmp_path / "daemon.mcap").read_bytes() == (tmp_path / "here.mcap").read_bytes()


def test_an_error_in_the_reader_is_raised_in_the_parent(tmp_path):
    path = write_with_corrupt_image(tmp_path / "bad.mcap", ImageFormat.PNG)
    with pytest.raises(RecordingError, match="corrupt PNG"):
        steps_of(path, reader_process=True)
    assert readers() == []


def test_what_the_reader_process_says_reaches_the_callers_on_warning_here(long, tmp_path):
    """The reading's warnings were said in the forked reader, to its copy of the caller's callback:
    ``estimate(on_warning=heard.append)`` from a notebook heard nothing of a truncated recording
    ("the rest is lost"), whose estimate then held 28 of 69 images (found by an API user's audit).
    They come back through the pipe and are said here, as with the reader in this process."""
    import os

    from aslam.app.estimate import estimate

    cut = tmp_path / "cut.mcap"
    whole = long.read_bytes()
    cut.write_bytes(whole[: len(whole) // 2])
    heard: dict[bool, list[tuple[str, int]]] = {}
    for reader_process in (True, False):
        said = heard.setdefault(reader_process, [])
        estimate(
            cut,
            tmp_path / f"e{reader_process}.mcap",
            EstimatorConfig(),
            reader_process=reader_process,
            on_warning=lambda line, said=said: said.append((line, os.getpid())),
        )
    assert heard[True] == heard[False]
    assert any("truncated" in line for line, _pid in heard[True])
    assert {pid for _line, pid in heard[True]} == {os.getpid()}


def test_steps_dropped_unread_stop_and_reap_their_reader(long):
    """Steps made and never iterated nor closed, then dropped (a notebook cell that failed before its
    loop): their reader was left blocked on its pipe, then a zombie until the next fork."""
    import gc
    import os

    steps = run_estimate(Recording(long).samples(), Estimator(EstimatorConfig()))
    pid = steps._reader._process.pid  # type: ignore[union-attr]
    assert os.path.exists(f"/proc/{pid}")
    del steps
    gc.collect()
    assert not os.path.exists(f"/proc/{pid}")  # stopped and reaped, not a zombie


def test_a_dropped_steps_finalizer_copied_into_a_later_readers_child_does_nothing_there(square):
    """``weakref.finalize`` is copied into every fork: steps left in a reference cycle when the next
    reader forked were collected in that child, whose finalizer then asked about a process that is
    not its child (``AssertionError: can only test a child process``, printed on stderr; a code
    review's finding). It closes its reader in the process that made it only. (A process of its
    own: the child's words reach its descriptor 2 unbuffered, as in a terminal.)"""
    import subprocess
    import sys

    script = f"""
import gc
from pathlib import Path
from aslam.app.pipeline import run_estimate
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator
from aslam.data_formats.recording import Recording

path = Path({str(square)!r})
gc.disable()
dropped = run_estimate(Recording(path).samples(), Estimator(EstimatorConfig()))
dropped.cycle = dropped
del dropped

def collected_in_the_child():
    gc.collect()
    yield from Recording(path).samples()

steps = run_estimate(collected_in_the_child(), Estimator(EstimatorConfig()))
gc.enable()
print(sum(1 for _ in steps))
"""
    unbuffered = {**os.environ, "PYTHONUNBUFFERED": "1"}
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=unbuffered
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) > 10
    assert done.stderr == ""
