"""The files of a sweep's results folder: the recordings' hashes, each task's result, the tables.

``aslam.app.sweep`` decides what they hold; this module owns their bytes: JSON documents written
whole under a temporary name and renamed (a task's result is kept the moment it finishes, so an
interrupted sweep loses nothing), and the tables encoded as Parquet and CSV by pyarrow.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

from aslam.data_formats.files import write_atomically
from aslam.data_formats.json_text import json_text

RESULTS_PARQUET = "results.parquet"
RESULTS_CSV = "results.csv"
TASKS_FOLDER = "tasks"
HASHES_FILE = "hashes.json"


def read_json_document(path: Path) -> Any:
    """The JSON document at ``path``, or None where it is missing or unreadable (a cache: a re-run
    then computes what it would have held)."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def write_json_document(path: Path, document: Any) -> None:
    """``document`` as indented, key-sorted JSON, written whole or not at all."""
    text = json_text(document, indent=1, sort_keys=True)
    write_atomically(path, lambda temporary: temporary.write_text(text))


def task_file(results_dir: Path, key: str) -> Path:
    """Where the result of the task with ``key`` is kept."""
    return Path(results_dir) / TASKS_FOLDER / f"{key[:16]}.json"


def table_file_bytes(table: Any) -> dict[str, bytes]:
    """A ``pyarrow.Table`` as ``results.parquet`` and ``results.csv`` hold it, by file name."""
    import pyarrow as pa
    import pyarrow.csv
    import pyarrow.parquet

    parquet, csv = pa.BufferOutputStream(), pa.BufferOutputStream()
    pyarrow.parquet.write_table(table, parquet)
    pyarrow.csv.write_csv(table, csv)
    return {RESULTS_PARQUET: parquet.getvalue().to_pybytes(), RESULTS_CSV: csv.getvalue().to_pybytes()}


def holds(path: Path, data: bytes) -> bool:
    """Whether the file at ``path`` already holds exactly ``data`` (then it is not written again)."""
    try:
        return path.stat().st_size == len(data) and path.read_bytes() == data
    except OSError:
        return False


def write_table_file(path: Path, data: bytes) -> None:
    """One table's bytes, written whole or not at all."""
    write_atomically(path, functools.partial(Path.write_bytes, data=data))
