"""Commands run at once on shared files (docs/reliability.md, "Running commands at once").

Another process is put at a chosen point of a command by wrapping one of its steps: the step
first does what the other process would (replace a file by a rename, as ``--force`` does), then
runs as it would. Every engine is the real one; nothing waits on a clock.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import square_route, write_square_recording

import aslam.app.estimate as estimate_module
import aslam.app.score as score_module
import aslam.data_formats.estimate as estimate_format
from aslam.cli.app import main
from aslam.data_formats.errors import CutWhileReadError
from aslam.data_formats.estimate import iter_keyframes, open_estimate, read_estimate
from aslam.data_formats.files import partial_name, remove_stale_partials

ONE_LAP = 16
"""Keyframes of one lap of the square route (its first 16 poses): another estimate's length."""


@pytest.fixture(scope="module")
def two_recordings(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The square route twice round, and once round drawn with another seed: two recordings of
    other lengths and other bytes."""
    folder = tmp_path_factory.mktemp("recordings")
    long, short = folder / "long.mcap", folder / "short.mcap"
    write_square_recording(long)
    write_square_recording(short, square_route()[:ONE_LAP], seed=8)
    return long, short


@pytest.fixture(scope="module")
def two_estimates(
    two_recordings: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("estimates")
    outputs = folder / "long.est.mcap", folder / "short.est.mcap"
    for recording, output in zip(two_recordings, outputs, strict=True):
        assert main(["estimate", str(recording), "-o", str(output), "-q", "--no-timing"]) == 0
    return outputs


def replaced_first(path: Path, by: Path, step: Callable[..., Any]) -> Callable[..., Any]:
    """``step``, but its first call replaces ``path`` by a copy of ``by`` first, atomically, as
    another command writing ``path`` with ``--force`` does."""
    done = False

    def wrapped(*args: Any, **kwargs: Any) -> Any:
        nonlocal done
        if not done:
            done = True
            copy = path.with_name(".other-writer")
            shutil.copyfile(by, copy)
            os.replace(copy, path)
        return step(*args, **kwargs)

    return wrapped


def test_a_report_reads_one_estimate_when_another_process_replaces_it_meanwhile(
    two_estimates: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """``report E`` while ``estimate R2 -o E --force`` runs: the estimate was opened by name for
    each of its passes, so the graph of one file met the keyframes of the other (and, in the same
    reader, one file's summary was applied to the other's bytes): 1 report in 25 succeeded, the
    others ended with ``incomplete MCAP file (no trailing magic)`` for a complete file, a wrong
    map error, or exit 70 (``35 steps, 55 counted``). Now the report is of the file it opened."""
    ours, theirs = two_estimates
    estimate = tmp_path / "E.mcap"
    shutil.copyfile(ours, estimate)
    alone, meanwhile = tmp_path / "alone.json", tmp_path / "meanwhile.json"
    assert main(["report", str(estimate), "-q", "--json", str(alone)]) == 0
    monkeypatch.setattr(
        score_module, "_session_truth", replaced_first(estimate, theirs, score_module._session_truth)
    )
    assert main(["report", str(estimate), "-q", "--json", str(meanwhile)]) == 0
    assert estimate.read_bytes() == theirs.read_bytes()  # it was replaced mid-report
    assert json.loads(meanwhile.read_text()) == json.loads(alone.read_text())


def test_an_estimate_is_of_the_recording_it_opened_when_another_process_replaces_it(
    two_recordings: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """``estimate R`` while ``record -o R --force`` (or ``import``) writes another recording there:
    the reader opened R by name for each read, and the recording's SHA-256 was read by name at
    the end, so an estimate recorded the size of one file, the digest of another and the keyframes
    of a third (9 of 11 estimates did so in a loop), or failed on a summary of the other file.
    Now the estimate reads, and names, the file it opened: the same bytes as with no one else."""
    ours, theirs = two_recordings
    recording = tmp_path / "R.mcap"
    shutil.copyfile(ours, recording)
    alone, meanwhile = tmp_path / "alone.mcap", tmp_path / "meanwhile.mcap"
    assert main(["estimate", str(recording), "-o", str(alone), "-q", "--no-timing"]) == 0
    monkeypatch.setattr(
        estimate_module, "run_estimate", replaced_first(recording, theirs, estimate_module.run_estimate)
    )
    assert main(["estimate", str(recording), "-o", str(meanwhile), "-q", "--no-timing"]) == 0
    assert recording.read_bytes() == theirs.read_bytes()
    assert meanwhile.read_bytes() == alone.read_bytes()


def test_a_file_cut_short_in_place_while_it_is_read_is_named_not_read_short(
    two_estimates: tuple[Path, Path], tmp_path: Path
):
    """An opened file guards against a rename, not against another process truncating the file in
    place (``truncate``, or ``cp`` over it, which reopens it with O_TRUNC): reads by offset then
    came short, so the SHA-256 an estimate stores of its recording was the digest of the part left,
    stored with the size of the whole, and a report's keyframes failed as ``corrupt MCAP data:
    EndOfFile``. Both now name the file cut short."""
    estimate = tmp_path / "E.mcap"
    shutil.copyfile(two_estimates[0], estimate)
    opened = open_estimate(estimate)
    opened.sha256()
    os.truncate(estimate, opened.size // 2)
    cut = re.escape(
        f"{estimate}: was cut to {opened.size // 2:,} bytes while it was read ({opened.size:,} when opened)"
    )
    with pytest.raises(CutWhileReadError, match=f"^{cut}"):
        opened.sha256()
    with pytest.raises(CutWhileReadError, match=f"^{cut}"):
        list(iter_keyframes(opened))


def test_a_report_whose_recording_is_cut_short_while_it_reads_the_truth_stops(
    two_recordings: tuple[Path, Path], two_estimates: tuple[Path, Path], tmp_path: Path, monkeypatch, capsys
):
    """The recording truncated by another process while ``report`` read its truth was taken as a
    damaged recording: a warning, then the report without ground truth, exit 0 (or 1 from a gate,
    which CI reads as a regression). As everywhere else, exit 2: read it again once it is whole."""
    recording, estimate = tmp_path / "R.mcap", tmp_path / "E.mcap"
    shutil.copyfile(two_recordings[0], recording)
    shutil.copyfile(two_estimates[0], estimate)
    real_open = score_module.open_input

    def cut_once_opened(path, *args, **kwargs):
        """The recording opened, then cut in half as its truth starts to be read."""
        opened = real_open(path, *args, **kwargs)
        read_truth = opened.ground_truth

        def cut_then_read():
            if recording.stat().st_size == two_recordings[0].stat().st_size:
                os.truncate(recording, recording.stat().st_size // 2)
            return read_truth()

        opened.ground_truth = cut_then_read
        return opened

    monkeypatch.setattr(score_module, "open_input", cut_once_opened)
    json_out = tmp_path / "s.json"
    code = main(["report", str(estimate), "--recording", str(recording), "--json", str(json_out)])
    assert code == 2
    err = capsys.readouterr().err
    assert f"{recording}: was cut to" in err and "without ground truth" not in err
    assert not json_out.exists()


def test_a_run_in_a_map_reads_one_map_when_another_process_replaces_it(
    two_recordings: tuple[Path, Path], two_estimates: tuple[Path, Path], tmp_path: Path, monkeypatch
):
    """``estimate R --map M`` while M is estimated again with ``--force``: the map's graph, its
    stored views and its digest were read by name one after the other, so a run could start in one
    map's places with another's views and name a third file's digest as its map. Now one file."""
    ours, theirs = two_estimates
    the_map = tmp_path / "M.est.mcap"
    shutil.copyfile(ours, the_map)
    alone, meanwhile = tmp_path / "alone.mcap", tmp_path / "meanwhile.mcap"
    run = ["estimate", str(two_recordings[1]), "--map", str(the_map), "-q", "--no-timing", "-o"]
    assert main([*run, str(alone)]) == 0
    monkeypatch.setattr(
        estimate_format, "read_place_views", replaced_first(the_map, theirs, estimate_format.read_place_views)
    )
    assert main([*run, str(meanwhile)]) == 0
    assert the_map.read_bytes() == theirs.read_bytes()
    assert meanwhile.read_bytes() == alone.read_bytes()
    assert read_estimate(meanwhile).metadata.prior_map is not None


@pytest.mark.parametrize("command", ["estimate", "report"])
def test_a_temporary_name_another_writer_holds_is_never_written_into(
    two_recordings: tuple[Path, Path], two_estimates: tuple[Path, Path], tmp_path: Path, command: str
):
    """The temporary name holds the process id, which is unique on one machine only: two
    ``estimate -o E --force`` in two containers (``unshare -pf``: both pid 1) sharing a folder
    opened one ``.E.mcap.partial-1``, and E was left torn (``corrupt MCAP data``) while both exited
    0 or the other said ``cannot write: No such file or directory``. Here the other writer's file
    is there before this process's (the same id: this process's own); it is left alone and
    the output is whole."""
    output = tmp_path / ("E.mcap" if command == "estimate" else "graph.json")
    theirs = partial_name(output)
    assert str(os.getpid()) in theirs.name
    theirs.write_bytes(b"another writer's bytes, still being written")
    if command == "estimate":
        argv = ["estimate", str(two_recordings[0]), "--no-timing", "-o", str(output)]
    else:
        argv = ["report", str(two_estimates[0]), "--graph", str(output)]
    assert main([*argv, "-q", "--force"]) == 0
    assert theirs.read_bytes() == b"another writer's bytes, still being written"
    if command == "estimate":
        assert output.read_bytes() == two_estimates[0].read_bytes()
    else:
        assert json.loads(output.read_text())["keyframes"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([output.name, theirs.name])


HOLDER = """
import fcntl, os, socket, sys
descriptor = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
fcntl.flock(descriptor, fcntl.LOCK_EX)
os.write(descriptor, f"{os.getpid()} {socket.gethostname()}\\n".encode())
print("held", flush=True)
sys.stdin.read()  # until the test closes the pipe
"""


def test_a_second_sweep_in_a_results_folder_is_refused_while_the_first_runs(
    two_recordings: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """Two ``aslam sweep S -o R`` at once (a CI job started twice, a sweep re-run while it still
    runs): both ran every task, twice the work, each writing the other's files. Now the second
    is refused at once, one line naming the process that holds the folder, nothing written; the
    lock goes with that process, however it ends. The first sweep is a process holding the lock
    as a sweep does (flock on ``R/.aslam.lock``, its id and host in it)."""
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'figures = ["keyframes"]\n[recordings]\npaths = ["{two_recordings[1]}"]\n')
    results = tmp_path / "results"
    results.mkdir()
    argv = ["sweep", str(sweep), "-o", str(results), "--workers", "1", "-q"]
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(results / ".aslam.lock")],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        assert main(argv) == 2
        assert capsys.readouterr().err == (
            f"aslam: error: {results}: another sweep (process {holder.pid} on {socket.gethostname()})"
            " is running in this results folder; wait for it to end, or give another folder\n"
        )
        assert [p.name for p in results.iterdir()] == [".aslam.lock"]
    finally:
        holder.communicate("")
    assert main(argv) == 0
    assert (results / "results.parquet").exists()


HOLDER_READ_ONLY = """
import sys
from pathlib import Path
from aslam.core.errors import InputError
from aslam.data_formats.files import check_folder_free, folder_lock
folder = Path(sys.argv[1])
with folder_lock(folder, holder="another sweep", what="results folder"):
    try:
        check_folder_free(folder, holder="another sweep", what="results folder")
    except InputError as err:
        print(err)
"""


def test_a_lock_file_this_user_may_not_write_still_holds_the_folder(tmp_path: Path):
    """``R/.aslam.lock`` left by another user (a sweep run as root in a container on a mounted
    folder, a colleague's in a shared one) could not be opened for writing, and a sweep in a folder
    whose every other file this user may replace was refused: ``R: cannot write: Permission
    denied``. It is now locked read-only (``flock`` needs no more), a second sweep still refused,
    and the last holder's line, of a process gone, is not named. A read-only bind mount of the lock
    file stands in for another user's (root may write any file)."""
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-rm", "true"]).returncode != 0:
        pytest.skip("needs unshare -rm (user and mount namespaces) to make one file read-only")
    results = tmp_path / "results"
    results.mkdir()
    gone = subprocess.Popen(["true"])
    gone.wait()
    lock = results / ".aslam.lock"
    lock.write_text(f"{gone.pid} {socket.gethostname()}\n")
    read_only = 'mount --bind "$1" "$1" && mount -o remount,bind,ro "$1" && exec "$2" -c "$3" "$4"'
    run = subprocess.run(
        ["unshare", "-rm", "sh", "-c", read_only, "sh", lock, sys.executable, HOLDER_READ_ONLY, results],
        capture_output=True,
        text=True,
    )
    assert (run.returncode, run.stderr) == (0, "")
    assert run.stdout == (
        f"{results}: another sweep is running in this results folder; wait for it to end, or give"
        " another folder\n"
    )
    assert lock.read_text() == f"{gone.pid} {socket.gethostname()}\n"


WRITER_ELSEWHERE = """
import fcntl, os, sys
descriptor = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT | os.O_EXCL)
fcntl.flock(descriptor, fcntl.LOCK_EX)
print("writing", flush=True)
sys.stdin.read()  # until the test closes the pipe
"""


def test_a_live_writers_temporary_file_in_another_container_is_not_called_left_over(
    two_recordings: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    """A temporary file is judged by the process id in its name, and an id is this machine's: an
    ``estimate -o E`` in another container (``unshare -pf``: its pid 3 none here) still writing
    ``.E.mcap.partial-3`` was named by an ``estimate -o E --force`` here as ``temporary file left
    by an interrupted run; delete it``, and a sweep's clean-up deleted such files in its folder.
    Now a writer holds a lock on its file, which tells: named and removed only once it is let go.
    The other container's writer is a process holding such a file under an id that is not alive."""
    gone_pid = subprocess.Popen(["true"])
    gone_pid.wait()
    output = tmp_path / "E.mcap"
    theirs = output.with_name(f".E.mcap.partial-{gone_pid.pid}")
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER_ELSEWHERE, str(theirs)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    argv = ["estimate", str(two_recordings[1]), "-o", str(output), "--force", "--no-timing"]
    try:
        assert writer.stdout is not None and writer.stdout.readline() == "writing\n"
        assert main(argv) == 0
        assert "temporary file left" not in capsys.readouterr().err
        assert remove_stale_partials(tmp_path) == []
        assert theirs.exists()
    finally:
        writer.communicate("")
    assert main(argv) == 0  # now it is left over, and named
    assert f"{theirs}: temporary file left by an interrupted run; delete it" in capsys.readouterr().err
    assert remove_stale_partials(tmp_path) == [theirs]
