"""Files that appear whole or not at all, and the checks every input and output path gets.

Every output the tool writes (recordings, estimates, graph and summary JSON, plots, contact sheets)
goes under a hidden temporary name in the folder of its real target and is renamed when complete,
so an interrupted run never leaves a half file under the final name. The rules (docs/usage.md,
"Inputs and outputs"):

* an output that resolves (``realpath``: symlinks and ``..`` followed) to an input of the same
  command, or to another of its outputs, is refused (exit 2), with or without ``--force``;
* an existing regular file is replaced only with ``--force``; a symlink is followed and its target
  replaced atomically; without ``--force`` an output is moved into place by a hard link, which
  cannot replace, so one another process wrote meanwhile is refused, not overwritten;
* a character device or FIFO (``/dev/null``, ``/dev/stdout``, a pipe) is written directly, never
  renamed over, and needs no ``--force``;
* inputs must be regular files (a FIFO or a device is refused at once instead of hanging).

Inside :func:`command_files` (the CLI opens one per command) the outputs are *staged*: complete
files wait under their temporary names and are renamed together when the command succeeds, so a
command that fails leaves none of its outputs, and outputs are checked against every input the
command opened, whenever it opened it. A result for stdout and the "wrote" lines wait for them too
(:attr:`CommandFiles.results`, :attr:`CommandFiles.after_commit`).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import glob
import hashlib
import io
import os
import socket
import stat
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, cast

from aslam.core.errors import InputError

MCAP_MAGIC = b"\x89MCAP0\r\n"
PARTIAL_MARK = ".partial-"
# Paths that name the process's own streams: written directly even when they resolve to a file.
_STREAM_PATHS = ("/dev/stdout", "/dev/stderr", "/dev/fd/", "/proc/self/fd/")


NAME_MAX_BYTES = 255
"""The longest file name most file systems take (ext4, XFS, btrfs, APFS, tmpfs)."""
_PARTIAL_EXTRA_BYTES = 1 + len(PARTIAL_MARK) + 10  # the dot, the mark, a process id (7 digits), -NN
_NAME_ATTEMPTS = 99


def partial_name(path: Path) -> Path:
    """Where ``path`` lives until it is complete: a hidden name in the same folder."""
    return path.with_name(f"{_partial_prefix(path)}{os.getpid()}")


def _partial_prefix(path: Path) -> str:
    """``.NAME.partial-``, how every temporary name of ``path`` starts. A name too long to take
    the suffix (a 255-byte name was refused as "File name too long" after all the work) is cut
    to its first bytes and a digest of the whole, so two long names in one folder stay apart."""
    name = os.fsencode(path.name)
    if len(name) + _PARTIAL_EXTRA_BYTES <= NAME_MAX_BYTES:
        return f".{path.name}{PARTIAL_MARK}"
    digest = hashlib.sha256(name).hexdigest()[:16]
    kept = name[: NAME_MAX_BYTES - _PARTIAL_EXTRA_BYTES - len(digest) - 1]
    return f".{os.fsdecode(kept)}~{digest}{PARTIAL_MARK}"


_held: dict[Path, int] = {}
"""This process's temporary files, each with a descriptor holding its ``flock`` until the file is
renamed into place or removed: a live writer's file, whatever its process id says elsewhere."""


def _temporary(target: Path, made: list[Path]) -> Path:
    """A temporary name of ``target`` no other writer holds: :func:`partial_name`, created empty
    and exclusively (``O_EXCL``), locked (``flock``) while it is written, and registered with the
    running command. A process id is unique on one machine only: two containers or hosts sharing a
    folder run processes of the same id, which opened one temporary file, each writing over the
    other's bytes and renaming it while the other still wrote (a torn output, exit 0). A name that
    is taken gets ``-2``, ``-3``, …; the lock tells a live writer's file from one left by a killed
    run where the id cannot (:func:`_writer_gone`).

    ``made`` (and the running command's list) get the name before the file exists, for the
    clean-ups: a Ctrl-C landing before this returned, or before its value was stored, left the
    file on disk with its descriptor and lock held (a library caller has no command to remove it at
    the end)."""
    first = partial_name(target)
    for attempt in range(1, _NAME_ATTEMPTS + 1):
        partial = first if attempt == 1 else first.with_name(f"{first.name}-{attempt}")
        # Named for the clean-ups before it exists: a signal handled just after os.open returned
        # (a syscall's return is where a loaded machine switches processes) found it unnamed.
        files = current()
        registers = [made] if files is None else [made, files.temporaries]
        for names in registers:
            names.append(partial)
        try:
            descriptor = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # another writer's: never ours to remove
            for names in registers:
                names.remove(partial)
            continue
        _held[partial] = descriptor
        with contextlib.suppress(OSError):  # a file system without locks: judged by the id alone
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return partial
    raise FileExistsError(errno.EEXIST, f"its {_NAME_ATTEMPTS} temporary names are taken", str(first))


def real_path(path: Path | str) -> Path:
    """``path`` with every symlink and ``..`` resolved (the file that would really be touched)."""
    return Path(os.path.realpath(path))


def is_stream_output(path: Path | str) -> bool:
    """True for outputs written directly: character devices, FIFOs, sockets and /dev/stdout-like names."""
    text = str(path)
    if text.startswith(_STREAM_PATHS):
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)


_STDOUT_NAMES = ("-", "/dev/stdout", "/dev/fd/1", "/proc/self/fd/1")
_STDERR_NAMES = ("/dev/stderr", "/dev/fd/2", "/proc/self/fd/2")


def is_stdout(target: Path | str) -> bool:
    """``-`` or a name of this process's stdout (``/dev/stdout``, ``/dev/fd/1``): a result for it goes
    through ``sys.stdout``, after what the command printed there, and adds to a file stdout was sent
    to (``>> log``) where opening the name would have truncated it. Names only: ``/dev/null`` is no
    stdout even when stdout was sent there."""
    return str(target) in _STDOUT_NAMES


def is_stderr(target: Path | str) -> bool:
    """A name of this process's stderr (``/dev/stderr``, ``/dev/fd/2``). While a command runs,
    descriptor 2 points at /dev/null (C libraries' own warnings, ``aslam.cli.app``) and ``sys.stderr``
    at the real stderr: a result for it is written there, not to the name."""
    return str(target) in _STDERR_NAMES


def _open_stream(path: Path) -> IO[bytes]:
    """A stream output opened for appending (a log stdout or stderr was sent to with ``>>`` keeps its
    lines); stderr's names open the real stderr (see :func:`is_stderr`)."""
    if is_stderr(path):
        with contextlib.suppress(AttributeError, ValueError, io.UnsupportedOperation):
            return os.fdopen(os.dup(sys.stderr.fileno()), "ab")
    return open(path, "ab")


class _CountedStream(io.BufferedIOBase):
    """A stream output that tells how much was written to it: the MCAP writer asks ``tell()`` for
    the offsets it indexes, and a pipe has no position (``Illegal seek``). The offsets count from the
    MCAP's first byte, which is what a reader of the stream sees first."""

    def __init__(self, raw: IO[bytes]) -> None:
        super().__init__()
        self._raw = raw
        self._written = 0

    def writable(self) -> bool:
        return True

    def write(self, data: bytes | bytearray | memoryview, /) -> int:  # type: ignore[override]
        self._raw.write(data)
        self._written += memoryview(data).nbytes
        return memoryview(data).nbytes

    def tell(self) -> int:
        return self._written

    def flush(self) -> None:
        self._raw.flush()

    def close(self) -> None:
        if not self.closed:
            try:
                super().close()  # flushes
            finally:
                self._raw.close()


# --- one command's files ----------------------------------------------------------------------


@dataclass(frozen=True)
class _Staged:
    partial: Path
    target: Path
    shown: Path
    error: type[InputError]


@dataclass
class CommandFiles:
    """The inputs one command read and the outputs it is writing (real paths), for the checks above."""

    force: bool | None = None
    """The command's ``--force``; None until the option is parsed (then outputs are not overwritten)."""
    on_warning: Callable[[str], None] | None = None
    inputs: dict[Path, Path] = field(default_factory=dict)
    outputs: dict[Path, Path] = field(default_factory=dict)
    staged: list[_Staged] = field(default_factory=list)
    temporaries: list[Path] = field(default_factory=list)
    """Every temporary file made, registered as it is created (before would leave a moment in which
    another writer's file of the same name counts as this command's): whatever an interrupt skips,
    the end of the command removes."""
    folders: list[Path] = field(default_factory=list)
    """Folders the command created for its outputs, deepest first: a failed command removes them."""
    results: list[tuple[bool, Callable[[], None]]] = field(default_factory=list)
    """Result documents for stdout or another stream (``report --json -``), each with whether it
    goes to stdout or stderr, written once every output is in place: a command whose outputs fail
    prints none (a pipeline would read a complete-looking result of a failed command); one that
    cannot be written takes them back. Those for other streams (``--json /dev/full``, a FIFO) go
    first, so that one failing leaves stdout empty too (the tables had been printed, then the error)."""
    after_commit: list[Callable[[], None]] = field(default_factory=list)
    """Run once the outputs are in place (the command's "wrote …" lines); dropped on a rollback."""
    superseded: list[Path] = field(default_factory=list)
    """Files of an output set this command does not write this time (:func:`remove_superseded`),
    removed once its outputs are in place; kept on a rollback."""
    owner_pid: int = field(default_factory=os.getpid)

    def warn(self, line: str) -> None:
        if self.on_warning is not None:
            self.on_warning(line)

    def commit(self) -> None:
        """Move every staged output to its final name, after checking them against every input.

        Without ``--force`` an output is only ever created, never replaced: one that another
        process wrote while this command ran (two runs given the same ``-o``) is refused, and the
        outputs this commit had already created are taken back, so the command leaves none.
        """
        if os.getpid() != self.owner_pid:
            return
        for item in self.staged:
            shown = self.inputs.get(item.target)
            if shown is not None:
                self.rollback()
                raise item.error(_input_conflict(shown), path=item.shown)
        staged, self.staged = self.staged, []
        created: list[Path] = []
        for i, item in enumerate(staged):
            try:
                if _move_into_place(item.partial, item.target, replace=bool(self.force)):
                    created.append(item.target)
            except OSError as err:
                for target in created:
                    _discard(target)
                self.staged = staged[i:]
                self.rollback()
                problem = (
                    _WRITTEN_MEANWHILE
                    if isinstance(err, FileExistsError)
                    else f"cannot write: {err.strerror or err}"
                )
                raise item.error(problem, path=item.shown) from err
        results, self.results = self.results, []
        try:
            for _, write in sorted(results, key=lambda result: result[0]):  # stable: in order within each
                write()
        except BaseException:
            for target in created:
                _discard(target)
            self.rollback()
            raise
        self._remove_temporaries()
        superseded, self.superseded = self.superseded, []
        for path in superseded:
            _remove_regular_file(path)
        self.folders = []
        after, self.after_commit = self.after_commit, []
        for announce in after:
            announce()

    def rollback(self) -> None:
        """Remove every staged output; nothing appears under their final names."""
        if os.getpid() != self.owner_pid:
            return
        staged, self.staged = self.staged, []
        self.results = []
        self.after_commit = []
        for item in staged:
            _discard(item.partial)
        self._remove_temporaries()
        folders, self.folders = self.folders, []
        for folder in folders:
            with contextlib.suppress(OSError):  # not empty: something else put a file there
                folder.rmdir()

    def _remove_temporaries(self) -> None:
        temporaries, self.temporaries = self.temporaries, []
        for path in temporaries:
            _discard(path)


def remove_superseded(path: Path, *, force: bool | None) -> None:
    """``path`` belongs to an output set this run writes but is not written this time (a
    trajectory's truth file without ground truth, a plot with nothing to draw): with ``force``
    (None: the running command's ``--force``) a file an earlier run left there goes, once this
    run's outputs are in place, so that every file of the set comes from one run (evo paired a new
    trajectory with an old truth file). Without it the existing file refused the run before any work."""
    files = current()
    if not (force or (force is None and files is not None and files.force)):
        return
    if files is None:
        _remove_regular_file(Path(path))
    else:
        files.superseded.append(real_path(Path(path)))


def _remove_regular_file(path: Path) -> None:
    """Remove ``path`` if it is a regular file (never a folder, a device or a FIFO named there)."""
    with contextlib.suppress(OSError):
        if stat.S_ISREG(os.lstat(path).st_mode):
            path.unlink()


def _discard(path: Path) -> None:
    """Remove ``path`` if it is there. A clean-up never fails in turn: it would hide the error that
    called for it (a read-only folder refuses even to unlink a file that was never made)."""
    with contextlib.suppress(OSError):
        path.unlink(missing_ok=True)
    _release(path)


def _release(partial: Path) -> None:
    """Let go of a temporary file this process held (renamed into place, or removed)."""
    descriptor = _held.pop(partial, None)
    if descriptor is not None:
        os.close(descriptor)


_WRITTEN_MEANWHILE = (
    "was written by another process while this command ran; refusing to overwrite it (use --force)"
)


def _move_into_place(partial: Path, target: Path, *, replace: bool) -> bool:
    """Rename ``partial`` to ``target``; True if that created ``target`` (nothing was there), so a
    command failing after it takes the file back, ``--force`` or not.

    Without ``replace`` the move is a hard link, which fails (``FileExistsError``) when ``target``
    exists, atomically, where a check before a rename would leave a moment for another writer. A
    file system without hard links (FAT, some network shares) gets that check, then the rename.
    """
    if not replace:
        try:
            os.link(partial, target)
        except FileExistsError:
            raise
        except OSError:  # no hard links here
            if os.path.lexists(target):
                raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(target)) from None
        else:
            _discard(partial)
            return True
    created = not os.path.lexists(target)
    os.replace(partial, target)
    _release(partial)
    return created


_current: CommandFiles | None = None


def current() -> CommandFiles | None:
    """The files of the command running in this process, or None outside :func:`command_files`."""
    if _current is not None and _current.owner_pid != os.getpid():
        return None  # a forked child reads; it never stages or removes the parent's files
    return _current


@contextlib.contextmanager
def command_files(*, on_warning: Callable[[str], None] | None = None) -> Iterator[CommandFiles]:
    """Track one command's inputs and outputs; rename its outputs together on success.

    Leaving the block with an exception removes every staged output (the caller commits on the
    outcomes that keep them, e.g. a failed quality gate, by calling ``commit()`` before raising).
    """
    global _current
    previous = _current
    files = CommandFiles(on_warning=on_warning)
    _current = files
    try:
        yield files
        files.commit()
    except BaseException:
        files.rollback()
        raise
    finally:
        _current = previous


LOCK_FILE = ".aslam.lock"


@contextlib.contextmanager
def folder_lock(folder: Path, *, holder: str, what: str) -> Iterator[None]:
    """Hold ``folder`` for this process, or fail at once naming the process that holds it.

    ``flock`` on ``folder/.aslam.lock``, which the kernel releases when the process ends however it
    ends (a SIGKILL leaves no stale lock); the file, left in place, says who held it last (``PID
    HOST``). ``holder`` names the kind of command (``another sweep``), ``what`` the folder (``results
    folder``). On a file system without locks (some network shares) the block runs unguarded.

    A lock file this process may not write (another user's: a sweep run as root in a container, a
    colleague's in a shared folder) is locked read-only, as ``flock`` allows, and keeps the last
    holder's line: refused for it, a user who may replace every file of the folder could not
    resume its sweep.
    """
    lock = Path(folder) / LOCK_FILE
    try:
        descriptor, named = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666), True
    except OSError as err:
        cannot = InputError(f"cannot write: {err.strerror or err}", path=folder)
        if not isinstance(err, PermissionError) and err.errno != errno.EROFS:
            raise cannot from err
        try:
            descriptor, named = os.open(lock, os.O_RDONLY), False
        except OSError:
            raise cannot from err
    try:
        if _locked(descriptor, folder, holder=holder, what=what) and named:
            os.ftruncate(descriptor, 0)
            os.pwrite(descriptor, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
        yield
    finally:
        os.close(descriptor)


def check_folder_free(folder: Path, *, holder: str, what: str) -> None:
    """Fail at once if a process holds ``folder`` (:func:`folder_lock`); writes nothing, so a command
    that may turn out to have nothing to write is refused before its work, not after."""
    try:
        descriptor = os.open(Path(folder) / LOCK_FILE, os.O_RDONLY)
    except OSError:
        return  # never held (a folder that cannot be read fails where it is read)
    try:
        _locked(descriptor, folder, holder=holder, what=what)
    finally:
        os.close(descriptor)  # releases the lock just taken


def _locked(descriptor: int, folder: Path, *, holder: str, what: str) -> bool:
    """Take the lock of an open lock file; whether it is held now (False: no locks on this file
    system). InputError naming the process that holds it."""
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        pid, _, host = os.pread(descriptor, 300, 0).decode("utf-8", "replace").strip().partition(" ")
        named = pid.isdigit() and host and (host != socket.gethostname() or _process_alive(int(pid)))
        who = f"{holder} (process {pid} on {host})" if named else holder  # not a holder gone since
        raise InputError(
            f"{who} is running in this {what}; wait for it to end, or give another folder", path=folder
        ) from None
    except OSError:
        return False
    return True


def make_output_folder(folder: Path) -> None:
    """Create ``folder`` and its missing parents for a command's outputs; if the command then
    fails, or is interrupted, the folders it created go with its files."""
    missing = []
    probe = Path(folder).absolute()
    while not os.path.lexists(probe):
        missing.append(probe)
        probe = probe.parent
    Path(folder).mkdir(parents=True, exist_ok=True)
    files = current()
    if files is not None:
        files.folders.extend(missing)


def note_force(force: bool) -> None:
    """Record the running command's ``--force`` (called by the CLI option's callback)."""
    files = current()
    if files is not None:
        files.force = bool(force)


def note_input(path: Path | str, *, error: type[InputError] = InputError) -> None:
    """Record ``path`` as an input of the running command; refused if it is one of its outputs."""
    files = current()
    if files is None:
        return
    real = real_path(path)
    if real in files.outputs:
        raise error(f"is also an output of this command ({files.outputs[real]})", path=path)
    files.inputs.setdefault(real, Path(path))


def _output_conflict(other: Path) -> str:
    return f"resolves to the same file as another output of this command ({other})"


def _input_conflict(shown: Path) -> str:
    return f"resolves to an input of this command ({shown}); refusing to overwrite it, even with --force"


def check_input_file(path: Path, *, error: type[InputError], what: str) -> int:
    """The size of ``path`` after checking it exists and is a regular file (no FIFO, device, folder).

    Never opens the file, so a FIFO is refused instead of blocking.
    """
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error("no such file", path=path) from None
    except OSError as err:
        raise error(f"cannot read: {err.strerror or err}", path=path) from err
    if stat.S_ISDIR(st.st_mode):
        raise error(f"is a directory, not {what}", path=path)
    if not stat.S_ISREG(st.st_mode):
        raise error(f"is not a regular file (a FIFO, socket or device), not {what}", path=path)
    note_input(path, error=error)
    _warn_stale(real_path(path))  # e.g. a recording whose writer was killed while replacing it
    return st.st_size


def utf8_text(text: str, *, undecodable: str = "replace") -> str:
    """``text`` as a UTF-8 file holds it (MCAP metadata, a Parquet or CSV column, a JSON document):
    the bytes of a file name that Python holds as surrogates (a C locale without UTF-8 mode spells
    ``café`` ``caf\\udcc3\\udca9``) read as UTF-8. A byte that is not UTF-8 (``$'\\xff.mcap'``,
    ``\\udcff`` to Python, which no UTF-8 writer takes) becomes U+FFFD, so the file is written;
    ``report`` then finds no recording at that name and says so (``--recording`` names it).
    ``undecodable="surrogateescape"`` keeps it ``\\udcff``, for JSON, which can spell it."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", undecodable)


def utf8_file_name(name: Path | str) -> str:
    """A file name as a UTF-8 file stores it to be found again (an estimate's recording and map):
    its bytes read as UTF-8, a byte that is not UTF-8 U+FFFD, as :func:`utf8_text`. Under a Latin-1
    locale Python spells the file ``café`` as ``cafÃ©``, which :func:`utf8_text` stores as those two
    letters, a name no file has under any locale."""
    return os.fsencode(name).decode("utf-8", "replace")


def file_name_from_utf8(text: str) -> Path:
    """The file a name read from a UTF-8 file names (an estimate's recording and map, a sweep
    file's paths): the inverse of :func:`utf8_file_name`, the name's UTF-8 bytes as this process's
    file system calls take them. Under a locale that is not UTF-8 (``LC_ALL=C`` with
    ``PYTHONUTF8=0``, a Latin-1 locale) Python spells the file ``café`` as ``caf\\udcc3\\udca9`` or
    ``cafÃ©``, and ``café`` itself named no file."""
    return Path(os.fsdecode(text.encode("utf-8", "surrogateescape")))


def utf8_metadata(metadata: Mapping[str, str]) -> dict[str, str]:
    """An MCAP metadata map with every value :func:`utf8_text`."""
    return {key: utf8_text(value) for key, value in metadata.items()}


def full_path(path: Path | str) -> Path:
    """``path`` absolute, with ``.`` and ``..`` folded away (symlinks kept: the name given, made
    canonical). What files record of the paths they name (an estimate's recording, a report's
    estimate), so the same file spelled ``../rec.mcap`` from another folder gives the same bytes.

    A ``..`` is the parent of the folder it follows as the file system has it: ``link/..`` is the
    parent of the folder ``link`` points to, not the folder holding ``link`` (folded as text, a
    recording named through a symlink was not found, and ``-o link/../out.mcap`` wrote elsewhere).
    So the part up to the last ``..`` is resolved, symlinks and all; the rest keeps its names."""
    absolute = Path(os.getcwd(), path)
    parts = absolute.parts
    if ".." not in parts:
        return Path(os.path.abspath(absolute))
    last = len(parts) - 1 - parts[::-1].index("..")
    return Path(os.path.abspath(os.path.join(os.path.realpath(Path(*parts[: last + 1])), *parts[last + 1 :])))


def check_output_folder(path: Path, *, what: str = "folder", outputs: Iterable[Path] = ()) -> None:
    """Fail before any work when ``path`` cannot be an output folder: a file, one of the command's
    other ``outputs``, or a folder to be made under a file or in a folder that cannot be written (the
    folder itself is made by whoever writes into it). An existing folder may be read-only: whether a
    file must be written in it is for its writer to say (a finished sweep's results are only read)."""
    path = Path(path)
    real = real_path(path)
    for given in outputs:
        if not is_stream_output(given) and real_path(given) == real:
            raise InputError(_output_conflict(Path(given)), path=path)
    if path.exists() and not path.is_dir():
        raise InputError(f"is a file, not a {what}", path=path)
    if not path.exists():
        above = next(folder for folder in path.absolute().parents if folder.exists())
        if not above.is_dir():
            raise InputError(f"cannot make the {what}: {above} is not a folder", path=path)
        problem = write_problem(above)
        if problem is not None:
            raise InputError(f"cannot make the {what} in {above}: {problem}", path=path)


def write_problem(folder: Path) -> str | None:
    """Why no file can be made in the existing ``folder`` (``Read-only file system``, ``Permission
    denied``: what the first write would say), or None; None too for a folder not there (whoever
    makes it finds out). Asked by work that would otherwise fail only at its first write."""
    try:
        read_only = os.statvfs(folder).f_flag & os.ST_RDONLY
    except OSError:
        return None
    if read_only:
        return os.strerror(errno.EROFS)
    return None if os.access(folder, os.W_OK | os.X_OK) else os.strerror(errno.EACCES)


def check_output_path(
    path: Path,
    *,
    force: bool | None,
    error: type[InputError] = InputError,
    inputs: Iterable[Path] = (),
    outputs: Iterable[Path] = (),
) -> None:
    """Fail before any work when ``path`` cannot, or must not, be written.

    ``force=None`` takes the running command's ``--force``. ``inputs`` and ``outputs`` are the
    command's other files, which the output must not resolve to (besides the inputs the running
    command has opened).
    """
    path = Path(path)
    if is_stream_output(path):
        return
    real = real_path(path)
    for given in inputs:
        if real_path(given) == real:
            raise error(_input_conflict(Path(given)), path=path)
    for given in outputs:
        if not is_stream_output(given) and real_path(given) == real:
            raise error(_output_conflict(Path(given)), path=path)
    files = current()
    if files is not None and real in files.inputs:
        raise error(_input_conflict(files.inputs[real]), path=path)
    try:
        mode = os.stat(real).st_mode if os.path.lexists(real) else None
    except OSError as err:  # a symlink loop, a folder we may not enter
        raise error(f"cannot be written: {err.strerror or err}", path=path) from err
    if mode is not None and stat.S_ISDIR(mode):
        raise error("is a directory", path=path)
    if mode is not None:
        if not stat.S_ISREG(mode):
            raise error("exists and is not a regular file; refusing to replace it", path=path)
        if not _forced(force):
            raise error("already exists; refusing to overwrite it (use --force)", path=path)
    if not real.parent.is_dir():
        # a symlink's own folder is there: the folder it points into is the one missing
        folder = path.parent if real_path(path.parent) == real.parent else real.parent
        if real.parent.exists():
            raise error(f"{folder} is not a folder", path=path)
        raise error(f"folder {folder} does not exist", path=path)
    problem = write_problem(real.parent)
    if problem is not None:  # found now, not after the work (a whole render, for a contact sheet)
        raise error(f"cannot write: {problem}", path=path)


def _forced(force: bool | None) -> bool:
    """``force``, or where None the running command's ``--force`` (no command: False)."""
    if force is not None:
        return force
    files = current()
    return bool(files is not None and files.force)


def _claim_output(path: Path, real: Path, error: type[InputError]) -> None:
    files = current()
    if files is None:
        return
    other = files.outputs.get(real)
    if other is not None:
        raise error(_output_conflict(other), path=path)
    files.outputs[real] = path


def stale_partials(target: Path) -> list[Path]:
    """Temporary files of ``target`` left by runs that were killed (their process is gone)."""
    try:
        candidates = list(target.parent.glob(f"{glob.escape(_partial_prefix(target))}*"))
    except OSError:
        return []
    return sorted(candidate for candidate in candidates if _writer_gone(candidate))


def remove_stale_partials(folder: Path) -> list[Path]:
    """Delete the temporary files in ``folder`` whose writer is gone (a sweep's workers killed
    mid-write by an interrupt); returns them. For folders a command owns, such as a sweep's
    results: elsewhere a stale file is only named (the next run's warning), never deleted."""
    try:
        removed = [c for c in sorted(folder.glob(f".*{PARTIAL_MARK}*")) if c.is_file() and _writer_gone(c)]
    except OSError:
        return []
    for candidate in removed:
        _discard(candidate)
    return removed


def _writer_gone(partial: Path) -> bool:
    """Whether the writer of a temporary file (``.NAME.partial-PID``) has ended: no process of that
    id here, and none holding the file's lock. The id alone is this machine's: a live writer in
    another container or on another host sharing the folder was taken for a killed run, its file
    named to be deleted (and a sweep deleted it)."""
    pid_text = partial.name.rpartition(PARTIAL_MARK)[2].partition("-")[0]  # -2, -3: a name taken
    if not pid_text.isdigit() or _process_alive(int(pid_text)):
        return False
    try:
        descriptor = os.open(partial, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return False  # gone already, or not ours to judge
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:
        pass  # no locks here: the id decides
    finally:
        os.close(descriptor)
    return True


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def _warn_stale(target: Path) -> None:
    files = current()
    if files is None:
        return
    for stale in stale_partials(target):
        files.warn(f"{stale}: temporary file left by an interrupted run; delete it")


class AtomicFile:
    """A binary output written under :func:`partial_name` and moved to ``path`` by :meth:`commit`.

    A stream output (``/dev/null``, a FIFO, ``/dev/stdout``) is written directly instead.
    ``force=None`` takes the running command's ``--force``.
    """

    def __init__(self, path: Path, *, force: bool | None, error: type[InputError] = InputError) -> None:
        self.path = Path(path)
        self._error = error
        check_output_path(self.path, force=force, error=error)
        self._replace = _forced(force)
        self.direct = is_stream_output(self.path)
        self.target = self.partial_path = self.path
        if not self.direct:
            self.target = real_path(self.path)
            _claim_output(self.path, self.target, error)
            _warn_stale(self.target)
        made: list[Path] = []
        try:
            if self.direct:  # appended to: a file stdout was sent to with ``>> log`` keeps its lines
                self.file: IO[bytes] = cast(IO[bytes], _CountedStream(_open_stream(self.path)))
            else:
                self.partial_path = _temporary(self.target, made)
                self.file = open(self.partial_path, "wb")  # noqa: SIM115 (closed by commit/abort)
        except BaseException as err:  # an interrupt between creating the file and holding it too
            for partial in made:
                _discard(partial)
            if isinstance(err, OSError):
                raise error(f"cannot write: {err.strerror or err}", path=self.path) from err
            raise
        self.closed = False

    def commit(self, finish: Callable[[], None] | None = None) -> None:
        """Run ``finish`` (the last writes), close, and rename to the final name.

        Inside :func:`command_files` the rename waits for the end of the command. On any failure,
        or an interrupt, the partial file is removed and nothing is left behind.
        """
        try:
            if finish is not None:
                finish()
            self.file.close()
            if not self.direct:
                _finish_output(self.partial_path, self.target, self.path, self._error, replace=self._replace)
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
        except OSError:
            pass  # e.g. a full disk refusing the last buffered bytes: the file goes anyway
        finally:
            if not self.direct:
                _discard(self.partial_path)


def _finish_output(
    partial: Path, target: Path, shown: Path, error: type[InputError], *, replace: bool
) -> None:
    """Rename now (an existing file replaced only if ``replace``: ``--force``), or stage the rename
    until the running command succeeds."""
    files = current()
    if files is None:
        try:
            _move_into_place(partial, target, replace=replace)
        except FileExistsError as err:
            raise error(_WRITTEN_MEANWHILE, path=shown) from err
        return
    if target in files.inputs:
        raise error(_input_conflict(files.inputs[target]), path=shown)
    files.staged.append(_Staged(partial, target, shown, error))


def write_atomically(
    path: Path,
    write: Callable[[Path], object],
    *,
    error: type[InputError] = InputError,
    force: bool | None = None,
) -> None:
    """Call ``write(temporary_path)``, then rename to ``path``; on failure nothing appears at ``path``.

    ``force=None``: the running command's ``--force`` inside :func:`command_files`, else overwrite
    (the library's historical behaviour). A stream output is written directly.
    """
    path = Path(path)
    if force is None and current() is None:
        force = True
    check_output_path(path, force=force, error=error)
    if is_stream_output(path):
        try:
            write(path)
        except OSError as err:
            raise error(f"cannot write: {err.strerror or err}", path=path) from err
        return
    target = real_path(path)
    _claim_output(path, target, error)
    _warn_stale(target)
    made: list[Path] = []
    try:
        temporary = _temporary(target, made)
        write(temporary)
        _finish_output(temporary, target, path, error, replace=_forced(force))
    except OSError as err:
        for partial in made:
            _discard(partial)
        raise error(f"cannot write: {err.strerror or err}", path=path) from err
    except BaseException:
        for partial in made:
            _discard(partial)
        raise


def write_text_output(target: str | Path, text: str) -> Path | None:
    """Write ``text`` to ``target``, ``-`` meaning stdout; the path written (None for stdout). The
    running command's ``--force`` decides whether a file there may be replaced.

    Inside :func:`command_files` a document for stdout or another stream (``/dev/stdout``, a pipe)
    waits in :attr:`CommandFiles.results` until every file output is in place.
    """
    path = None if str(target) == "-" else Path(target)
    if is_stdout(target) or is_stderr(target):
        if path is not None:
            check_output_path(path, force=None)
        stream = "stderr" if is_stderr(target) else "stdout"
        write: Callable[[], None] = functools.partial(_write_standard_stream, text, stream)
    else:
        assert path is not None
        write = functools.partial(
            write_atomically, path, functools.partial(_write_text, text=text), force=None
        )
    files = current()
    if files is not None and (path is None or is_stream_output(path)):
        files.results.append((path is None or is_stdout(path) or is_stderr(path), write))
    else:
        write()
    return path


def _write_text(path: Path, text: str) -> None:
    """``text`` into a new temporary file, or appended to a stream (a FIFO, ``/dev/fd/3`` sent to a
    file with ``3>> log``, which keeps its lines)."""
    if is_stream_output(path):
        with _open_stream(path) as stream:
            stream.write(text.encode("utf-8"))
        return
    with open(path, "w", encoding="utf-8") as file:
        file.write(text)


def _write_standard_stream(text: str, name: str) -> None:
    """``text`` on ``sys.stdout`` or ``sys.stderr`` (``name``); a failure other than a closed pipe
    (the CLI's exit 141) names the stream, also where the command's outputs are committed, after
    its own code has returned."""
    stream = getattr(sys, name)
    try:
        stream.write(text)
        stream.flush()
    except BrokenPipeError:
        raise
    except OSError as err:
        raise InputError(err.strerror or str(err), path=name) from err


def open_mcap_input(path: Path, *, error: type[InputError], what: str) -> tuple[int, int]:
    """``(descriptor, size)`` of ``path`` opened for reading, after checking it is a readable,
    non-empty regular file that starts like MCAP. The size is the opened file's: another process
    replacing ``path`` by a rename meanwhile (``estimate --force`` rewriting an estimate that
    ``report`` reads) changes nothing the caller reads through the descriptor."""
    check_input_file(path, error=error, what=what)
    try:
        # O_NONBLOCK: a FIFO put under the name since the check is refused below, never waited on
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as err:
        raise error(f"cannot read: {err.strerror or err}", path=path) from err
    try:
        st = os.fstat(descriptor)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"is not a regular file (a FIFO, socket or device), not {what}", path=path)
        if st.st_size == 0:
            raise error(f"empty file (0 bytes), not {what}", path=path)
        if os.pread(descriptor, len(MCAP_MAGIC), 0) != MCAP_MAGIC:
            raise error("not an MCAP file (bad magic bytes at the start)", path=path)
    except OSError as err:
        os.close(descriptor)
        raise error(f"cannot read: {err.strerror or err}", path=path) from err
    except BaseException:
        os.close(descriptor)
        raise
    return descriptor, st.st_size


def source_files(path: Path) -> list[Path]:
    """The files that hold a source, in a stable order: the file itself, or a bag folder's files.

    A rosbag2 folder's are its metadata.yaml and the storage files it lists (what rosbags reads),
    where it lists them: any other file beside them (a README, a sweep's results written into the
    folder) is no part of the bag, and counted as one it changed the bag's identity, so a sweep's
    own writing there failed each of its tasks as "not the bytes planned". Else every file in it.
    """
    path = Path(path)
    if not path.is_dir():
        return [path]
    listed = _rosbag2_files(path)
    if listed is not None:
        return listed
    return sorted(p for p in path.iterdir() if p.is_file())


ROSBAG2_METADATA_MAX_BYTES = 4 * 2**20
"""The largest rosbag2 metadata.yaml read. One is a few kilobytes (200 KB for a bag split a thousand
times); YAML parses at about a megabyte a second, and one with a 50 MB value kept ``info`` 44 s and
``estimate`` over a minute before they said anything."""


def rosbag2_information(folder: Path) -> dict | None:
    """A rosbag2 folder's metadata.yaml, its ``rosbag2_bagfile_information`` mapping; None where the
    folder has none or rosbags would refuse it (its reader then names the problem), or it is larger
    than ``ROSBAG2_METADATA_MAX_BYTES`` (the bag's open refuses it)."""
    metadata = folder / "metadata.yaml"
    if not metadata.is_file() or metadata.stat().st_size > ROSBAG2_METADATA_MAX_BYTES:
        return None
    import ruamel.yaml

    try:
        info = ruamel.yaml.YAML(typ="safe").load(metadata.read_text())["rosbag2_bagfile_information"]
    except Exception:
        return None
    return info if isinstance(info, dict) else None


def _rosbag2_files(folder: Path) -> list[Path] | None:
    """metadata.yaml and the files its ``relative_file_paths`` lists, by name; None where the folder
    has no readable metadata.yaml, or one that lists no file by a plain name in the folder."""
    names = (rosbag2_information(folder) or {}).get("relative_file_paths")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        return None
    files = [folder / name for name in names]
    if any(file.parent != folder or file.name in ("", ".", "..") for file in files):
        return None
    return sorted({folder / "metadata.yaml", *files})


def source_size_bytes(path: Path) -> int:
    """Bytes of a source: the file, or a bag folder's files summed (:func:`source_files`)."""
    return sum(file.stat().st_size for file in source_files(path))


def source_sha256(path: Path, stop: threading.Event | None = None) -> str:
    """SHA-256 of a recording's bytes (one file, or a bag folder's files in name order): its identity,
    wherever it lives. ``stop`` set: return early (the digest is then meaningless). InputError on a
    read failure."""
    sha = hashlib.sha256()
    try:
        for file in source_files(path):
            if not stat.S_ISREG(os.stat(file).st_mode):  # a FIFO would block, /dev/zero never end
                raise InputError("is not a regular file (a FIFO, socket or device)", path=file)
            with file.open("rb") as f:
                hash_file(sha, f, stop)
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", path=path) from err
    return sha.hexdigest()


def hash_file(sha: hashlib._Hash, f: IO[bytes], stop: threading.Event | None) -> None:
    """Feed ``f``, from where it is to its end, to ``sha`` in blocks, until ``stop`` is set."""
    while not (stop is not None and stop.is_set()):
        block = f.read(4 * 1024 * 1024)
        if not block:
            return
        sha.update(block)
