"""TOML files the tool reads: an estimator configuration (``estimate --config``), a sweep file.

Read whole, a UTF-8 byte-order mark skipped; every read or parse problem one ConfigError naming
the file. What the document must hold is checked by its reader (``aslam.app.config_file``,
``aslam.app.sweep_file``).
"""

from __future__ import annotations

import codecs
import sys
import tomllib
from pathlib import Path
from typing import Any

from aslam.core.errors import ConfigError
from aslam.data_formats.files import check_input_file

MAX_FILE_BYTES = 10_000_000
"""A configuration or a sweep is a page of text; the bound keeps a wrong file (a recording given as
``--config``) from being read whole before it is refused."""


def read_toml(path: Path, *, what: str) -> dict[str, Any]:
    """The TOML document at ``path``; ConfigError naming the file on any read or parse problem. A
    UTF-8 byte-order mark (Windows editors write one) is skipped, as in pose files: it was refused
    as "Invalid statement (at line 1, column 1)", a line the file seems not to have.

    Only a regular file is read: a FIFO was waited on for ever and ``/dev/zero`` read until the
    machine ran out of memory."""
    if check_input_file(Path(path), error=ConfigError, what=what) > MAX_FILE_BYTES:
        raise ConfigError(f"is larger than {MAX_FILE_BYTES:,} bytes, not {what}", path=path)
    try:
        return tomllib.loads(Path(path).read_bytes().removeprefix(codecs.BOM_UTF8).decode("utf-8"))
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror or err}", path=path) from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"not valid TOML ({err})", path=path) from err
    except ValueError as err:  # Python refuses to read an integer of thousands of digits
        raise ConfigError(
            f"a number of more than {sys.get_int_max_str_digits():,} digits", path=path
        ) from err
