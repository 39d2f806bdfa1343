"""Files that appear whole or not at all, and the checks every input and output path gets.

Every output the tool writes (recordings, estimates, graph and summary JSON, plots) goes under a
hidden temporary name in the same folder and is renamed when complete, so an interrupted run
never leaves a half file under the final name.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO

from aslam.core.errors import InputError

MCAP_MAGIC = b"\x89MCAP0\r\n"


def partial_name(path: Path) -> Path:
    """Where ``path`` lives until it is complete: a hidden name in the same folder."""
    return path.with_name(f".{path.name}.partial-{os.getpid()}")


def check_output_path(path: Path, *, force: bool, error: type[InputError] = InputError) -> None:
    """Fail before any work when ``path`` cannot, or must not, be written."""
    if path.is_dir():
        raise error("is a directory", path=path)
    if path.exists() and not force:
        raise error("already exists; refusing to overwrite it (use --force)", path=path)
    if not path.parent.is_dir():
        raise error(f"folder {path.parent} does not exist", path=path)


def check_mcap_input(path: Path, *, error: type[InputError], what: str) -> int:
    """The size of ``path`` after checking it is a readable, non-empty file that starts like MCAP."""
    if not path.exists():
        raise error("no such file", path=path)
    if path.is_dir():
        raise error(f"is a directory, not {what}", path=path)
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as err:
        raise error(f"cannot read: {err.strerror or err}", path=path) from err
    if size == 0:
        raise error(f"empty file (0 bytes), not {what}", path=path)
    if head != MCAP_MAGIC:
        raise error("not an MCAP file (bad magic bytes at the start)", path=path)
    return size


class AtomicFile:
    """A binary output written under :func:`partial_name` and moved to ``path`` by :meth:`commit`."""

    def __init__(self, path: Path, *, force: bool, error: type[InputError] = InputError) -> None:
        self.path = Path(path)
        self._error = error
        check_output_path(self.path, force=force, error=error)
        self.partial_path = partial_name(self.path)
        try:
            self.file: IO[bytes] = self.partial_path.open("wb")
        except OSError as err:
            raise error(f"cannot write: {err.strerror or err}", path=self.path) from err
        self.closed = False

    def commit(self, finish: Callable[[], None] | None = None) -> None:
        """Run ``finish`` (the last writes), close, and rename to the final name.

        On any failure, or an interrupt, the partial file is removed and nothing is left behind.
        """
        try:
            if finish is not None:
                finish()
            self.file.close()
            os.replace(self.partial_path, self.path)
        except OSError as err:
            self.abort()
            raise self._error(f"cannot write: {err.strerror or err}", path=self.path) from err
        except BaseException:
            self.abort()
            raise
        self.closed = True

    def abort(self) -> None:
        """Drop the partial file; nothing appears under the final name."""
        self.closed = True
        try:
            self.file.close()
        finally:
            self.partial_path.unlink(missing_ok=True)


def write_atomically(
    path: Path, write: Callable[[Path], None], *, error: type[InputError] = InputError
) -> None:
    """Call ``write(temporary_path)``, then rename to ``path``; on failure nothing appears at ``path``."""
    path = Path(path)
    check_output_path(path, force=True, error=error)
    temporary = partial_name(path)
    try:
        write(temporary)
        os.replace(temporary, path)
    except OSError as err:
        raise error(f"cannot write: {err.strerror or err}", path=path) from err
    finally:
        temporary.unlink(missing_ok=True)


def source_files(path: Path) -> list[Path]:
    """The files that hold a source, in a stable order: the file itself, or a bag folder's files."""
    path = Path(path)
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.is_file())
    return [path]


def source_sha256(path: Path, stop: threading.Event | None = None) -> str:
    """SHA-256 of a recording's bytes (one file, or a bag folder's files in name order): its identity,
    wherever it lives. ``stop`` set: return early (the digest is then meaningless). InputError on a
    read failure."""
    sha = hashlib.sha256()
    try:
        for file in source_files(path):
            with file.open("rb") as f:
                while not (stop is not None and stop.is_set()):
                    block = f.read(4 * 1024 * 1024)
                    if not block:
                        break
                    sha.update(block)
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from err
    return sha.hexdigest()
