"""One reader object per MCAP file we do not trust: indexed when we can, linear up to damage.

``McapFile`` checks the path, opens it once and reads the summary once; recordings, ``aslam info``,
image counts and estimate files are all served from it. Every later read goes through that one
descriptor, by offset (``pread``): what one ``McapFile`` serves is one file's bytes even when another
process replaces the name meanwhile (``estimate --force`` rewriting the estimate ``report`` reads,
``record --force`` the recording ``estimate`` reads), never one file's summary applied to another's.

An intact file (trailing magic, a footer, a summary with chunk indexes) is read through
``mcap.reader.SeekingReader`` in log-time order: it seeks from chunk to chunk, holding only the
chunks that overlap in time. Anything else (no summary, a file cut short, a file still being
written) is read front to back with ``mcap.stream_reader.StreamReader`` through a wrapper that
refuses to read past the end of the file, so the read stops cleanly at the first damaged record and
everything intact before it is kept. Either way each chunk's CRC is checked: a flipped bit in a
chunk that still decompresses (or is not compressed: a raw image, a map's place views) is an error,
never a wrong value read on. Every exception from the mcap libraries becomes the caller's
error type (``RecordingError``, ``EstimateError``) naming the file; nothing else escapes.
"""

from __future__ import annotations

import hashlib
import io
import os
import threading
import weakref
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.summary import Summary

from aslam.core.errors import InputError
from aslam.data_formats.errors import CutWhileReadError, RecordingError
from aslam.data_formats.files import MCAP_MAGIC as MAGIC
from aslam.data_formats.files import hash_file, open_mcap_input

_FOOTER_RECORD_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc


class _PastEnd(Exception):
    """A record runs past the end of the file (raised inside mcap's stream reader, caught here)."""


class _BoundedFile:
    """A read-only view of a file that raises ``_PastEnd`` instead of reading short.

    mcap's ``ReadDataStream`` accepts short reads silently (and a bad length would make it try to
    allocate that much); with this wrapper a cut-off record stops the read at its first byte.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self._stream = stream
        self._size = size
        self._pos = stream.tell()

    def read(self, n: int = -1) -> bytes:
        if n < 0:
            n = self._size - self._pos
        if n > self._size - self._pos:
            raise _PastEnd
        data = self._stream.read(n)
        self._pos += len(data)
        if len(data) < n:
            raise _PastEnd
        return data

    def tell(self) -> int:
        return self._pos


class _Pinned(io.RawIOBase):
    """A descriptor read at a position of its own: by offset (``os.pread``), so the readers of one
    ``McapFile`` never move each other, nor a forked child's. Closing it leaves the descriptor open.

    The file is read as ``size`` bytes long, its size when opened; a read that finds fewer (another
    process truncated the file in place, which a descriptor does not guard against as it does a
    rename) raises ``cut_short()`` rather than reading short: read short, the digest of a prefix was
    stored with the size of the whole, and an index read as damage (``corrupt MCAP data: EndOfFile``)."""

    def __init__(self, descriptor: int, size: int, cut_short: Callable[[], Exception]) -> None:
        super().__init__()
        self._descriptor = descriptor
        self._size = size
        self._cut_short = cut_short
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")[: max(0, self._size - self._pos)]
        got = os.preadv(self._descriptor, [view], self._pos)  # into the buffer: no copy of a chunk
        if got < len(view):
            raise self._cut_short()
        self._pos += got
        return got

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: self._size}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def tell(self) -> int:
        return self._pos


@dataclass(frozen=True)
class Truncation:
    """Where a linear read stopped: the intact data ends at ``at_byte`` of a ``size``-byte file."""

    at_byte: int
    size: int


class McapFile:
    """The messages of one MCAP file in time order, and what is known about its channels.

    The path is checked and the summary read once, here. ``channels`` maps topic → schema name.
    With a usable summary it is complete from the start (``complete_channels`` is True); on a
    linear read it grows as channel records are met. ``truncation`` is set once a linear read has
    stopped at damage. The file is opened once, here, and read by offset: every read is of the file
    that was at ``path`` then, and the object may cross a fork (the child reads the same file).

    ``error`` is the exception type raised for this kind of file, ``what`` names the kind in
    messages; ``require_complete`` refuses a file without its trailing magic (a file written by
    a writer that did not finish) instead of reading it linearly.
    """

    def __init__(
        self,
        path: Path,
        *,
        error: type[InputError] = RecordingError,
        what: str = "an MCAP recording",
        require_complete: bool = False,
        on_warning: Callable[[str], None] | None = None,
    ) -> None:
        self.path = Path(path)
        self._error_type = error
        self._descriptor, self.size = open_mcap_input(self.path, error=error, what=what)
        weakref.finalize(self, os.close, self._descriptor)
        self._warn = on_warning or (lambda _message: None)
        if require_complete and not self._ends_intact():
            raise error("incomplete MCAP file (no trailing magic); was it cut short?", path=self.path)
        self.truncation: Truncation | None = None
        self.channels: dict[str, str] = {}
        self.message_counts: dict[str, int] | None = None
        self._summary = self._read_summary()
        self.complete_channels = self._summary is not None
        if self._summary is not None:
            schemas = self._summary.schemas
            for channel in self._summary.channels.values():
                schema = schemas.get(channel.schema_id)
                self.channels[channel.topic] = schema.name if schema is not None else ""
            stats = self._summary.statistics
            if stats is not None:
                counts: dict[str, int] = {}
                for channel_id, count in stats.channel_message_counts.items():
                    counted = self._summary.channels.get(channel_id)
                    if counted is not None:
                        counts[counted.topic] = counts.get(counted.topic, 0) + count
                self.message_counts = counts

    def _error(self, problem: str, err: BaseException | None = None) -> InputError:
        if isinstance(err, CRCValidationError):  # the library's own words name no place in the file
            return self._error_type(f"{problem}: a chunk fails its CRC check (damaged bytes)", path=self.path)
        detail = f": {type(err).__name__}: {err}" if err is not None else ""
        return self._error_type(f"{problem}{detail}", path=self.path)

    def _open(self) -> io.BufferedReader:
        """A buffered reader of the opened file, from its start."""
        return io.BufferedReader(_Pinned(self._descriptor, self.size, self._cut_short))

    def _cut_short(self) -> InputError:
        now = os.fstat(self._descriptor).st_size
        return CutWhileReadError(
            f"was cut to {now:,} bytes while it was read ({self.size:,} when opened): another process"
            " truncated it; read it again once it is whole",
            path=self.path,
        )

    def sha256(self, stop: threading.Event | None = None) -> str:
        """SHA-256 of the opened file's bytes (the file read, whatever is at its name now). ``stop``
        set: return early (the digest is then meaningless)."""
        sha = hashlib.sha256()
        try:
            with self._open() as f:
                hash_file(sha, f, stop)
        except OSError as err:
            raise self._error("cannot read", err) from err
        return sha.hexdigest()

    def message_count(self, topic: str) -> int | None:
        """Messages on ``topic`` from the summary's statistics, or None when the file has none."""
        if self.message_counts is None:
            return None
        return self.message_counts.get(topic, 0)

    # --- summary ------------------------------------------------------------------------------

    def _ends_intact(self) -> bool:
        if self.size < 2 * len(MAGIC):
            return False
        try:
            with self._open() as f:
                f.seek(self.size - len(MAGIC))
                return f.read(len(MAGIC)) == MAGIC
        except OSError as err:
            raise self._error("cannot read", err) from err

    def _read_summary(self) -> Summary | None:
        """The summary if the file ends intact and has a consistent chunk index, else None."""
        if self.size < 2 * len(MAGIC) + _FOOTER_RECORD_SIZE or not self._ends_intact():
            return None  # cut short or still being written: read linearly
        try:
            with self._open() as f:
                reader = SeekingReader(f, record_size_limit=self.size)
                summary = reader.get_summary()
        except OSError as err:
            raise self._error("cannot read", err) from err
        except InputError:  # cut short meanwhile
            raise
        except Exception as err:  # mcap raises many types on a damaged summary
            self._warn(f"{self.path}: unreadable summary section ({err}); reading the file linearly")
            return None
        if summary is None or not summary.chunk_indexes:
            return None
        for index in summary.chunk_indexes:
            if index.chunk_start_offset + index.chunk_length > self.size:
                self._warn(f"{self.path}: chunk index points past the end of the file; reading linearly")
                return None
        for channel in summary.channels.values():
            if channel.schema_id != 0 and channel.schema_id not in summary.schemas:
                self._warn(f"{self.path}: summary names a missing schema; reading the file linearly")
                return None
        return summary

    # --- messages -----------------------------------------------------------------------------

    def messages(self, topics: Iterable[str] | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """The messages on ``topics`` (None: all) in log-time order.

        On a linear read the order is log-time order within each chunk and file order between
        chunks (MCAP writers write chunks in time order; sorting across chunks would need the index).
        """
        wanted = None if topics is None else set(topics)
        if self._summary is not None:
            yield from self._indexed_messages(wanted)
        else:
            yield from self._linear_messages(wanted)

    def count_messages(self) -> dict[str, int]:
        """Messages per topic: from the summary's statistics, else by reading the file (up to damage)."""
        if self.message_counts is not None:
            return dict(self.message_counts)
        counts: dict[str, int] = {}
        for _schema, channel, _message in self.messages(None):
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        return counts

    def _indexed_messages(self, wanted: set[str] | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        with self._open() as f:
            reader = SeekingReader(f, record_size_limit=self.size, validate_crcs=True)
            topics = None if wanted is None else sorted(wanted)
            iterator = reader.iter_messages(topics=topics, log_time_order=True)
            while True:
                try:
                    item = next(iterator)
                except StopIteration:
                    return
                except InputError:  # cut short meanwhile
                    raise
                except Exception as err:  # zstd, struct, McapError, ... on a damaged chunk
                    raise self._error("corrupt MCAP data", err) from err
                yield item

    def _linear_records(self, f: IO[bytes]) -> Iterator[object]:
        """Top-level records (chunks not opened) up to the footer or the first damaged record."""
        bounded = _BoundedFile(f, self.size)
        records = StreamReader(bounded, emit_chunks=True, record_size_limit=self.size).records  # type: ignore[arg-type]
        intact_end = len(MAGIC)
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except (_PastEnd, EndOfFile, RecordLengthLimitExceeded):
                # A record runs past the end of the file (or claims to be longer than the file).
                self.truncation = Truncation(at_byte=intact_end, size=self.size)
                return
            except InputError:  # cut short meanwhile
                raise
            except Exception as err:
                raise self._error(f"corrupt MCAP record after byte {intact_end}", err) from err
            intact_end = bounded.tell()
            yield record
            if isinstance(record, Footer):
                # The trailing magic comes next; StreamReader reads it after yielding the footer.
                try:
                    next(records, None)
                except Exception:  # the trailing magic is cut or wrong; every record was read
                    self.truncation = Truncation(at_byte=intact_end, size=self.size)
                return

    def _linear_messages(self, wanted: set[str] | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}

        def add_channel(channel: Channel) -> None:
            channels[channel.id] = channel
            schema = schemas.get(channel.schema_id)
            self.channels.setdefault(channel.topic, schema.name if schema is not None else "")

        def pick(message: Message) -> tuple[Schema | None, Channel, Message] | None:
            channel = channels.get(message.channel_id)
            if channel is None:
                raise self._error(f"message at log time {message.log_time} names unknown channel")
            if wanted is not None and channel.topic not in wanted:
                return None
            return schemas.get(channel.schema_id), channel, message

        with self._open() as f:
            for record in self._linear_records(f):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    add_channel(record)
                elif isinstance(record, Message):
                    item = pick(record)
                    if item is not None:
                        yield item
                elif isinstance(record, Chunk):
                    try:
                        inner = breakup_chunk(record, validate_crc=True)
                    except Exception as err:
                        raise self._error("corrupt MCAP chunk", err) from err
                    messages = []
                    for rec in inner:  # every channel of the chunk is known before its messages
                        if isinstance(rec, Schema):
                            schemas[rec.id] = rec
                        elif isinstance(rec, Channel):
                            add_channel(rec)
                        elif isinstance(rec, Message):
                            messages.append(rec)
                    messages.sort(key=lambda m: m.log_time)  # one chunk, bounded
                    for message in messages:
                        item = pick(message)
                        if item is not None:
                            yield item

    # --- metadata -----------------------------------------------------------------------------

    def metadata(self, name: str) -> dict[str, str] | None:
        """The first metadata record called ``name``, or None."""
        try:
            if self._summary is not None:
                if not any(index.name == name for index in self._summary.metadata_indexes):
                    return None
                with self._open() as f:
                    reader = SeekingReader(f, record_size_limit=self.size)
                    for record in reader.iter_metadata():
                        if record.name == name:
                            return dict(record.metadata)
                return None
            with self._open() as f:
                for linear in self._linear_records(f):
                    if isinstance(linear, Metadata) and linear.name == name:
                        return dict(linear.metadata)
            return None
        except InputError:
            raise
        except Exception as err:
            raise self._error("corrupt metadata record", err) from err
