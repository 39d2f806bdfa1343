"""Which aslam wrote a file: the version stamped into recordings and estimate files, and the code
version a cache of computed results is keyed by.

The one place the version is written down: ``pyproject.toml`` reads it from here
(``[tool.setuptools.dynamic]``), so asking costs nothing. Looking it up in the installed
package's metadata instead (``importlib.metadata``) took 25 ms of every estimate's start-up.
"""

import functools
import hashlib
from pathlib import Path

VERSION = "0.1.0"
#: The subpackages whose code decides a render's bytes and an estimate's and a score's figures (the
#: CLI's texts decide none).
RESULT_PACKAGES = ("app", "core", "data_formats", "recorder")
#: A module's source, or its bytecode where an install ships that alone (``__pycache__`` is not read).
MODULE_SUFFIXES = (".py", ".pyc")


def tool_version() -> str:
    return VERSION


def code_version() -> str:
    """``VERSION+src.`` and the first 12 hex digits of the SHA-256 of the source of
    ``RESULT_PACKAGES``: what a sweep's cached renders and task results are keyed by. VERSION alone
    stayed 0.1.0 through every change of the recorder, the estimator and the scoring, so a sweep
    folder kept across an upgrade had its old results reused as the new code's."""
    return f"{VERSION}+src.{_source_sha256()[:12]}"


@functools.cache
def _source_sha256() -> str:
    """SHA-256 of every module file of ``RESULT_PACKAGES``, by name and bytes (a few ms, once): the
    ``.py`` sources, and the ``.pyc`` files of an install without them (``compileall -b``, the
    sources removed), which had no ``.py`` to hash and so shared one version whatever their code.
    Such an install's version changes at each compilation (the bytecode holds the source's time and
    path): a sweep folder's results are computed again, never taken from other code.

    Only a name Python imports counts: Emacs's lock of a file being edited, ``.#estimator.py``, a
    link to nothing, stopped every sweep ("No such file or directory", exit 2), and macOS's
    ``._estimator.py`` beside a module copied from its disks changed the version."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for package in RESULT_PACKAGES:
        modules = (
            path
            for path in (root / package).iterdir()
            if path.suffix in MODULE_SUFFIXES and path.stem.isidentifier()
        )
        for source in sorted(modules):
            data = source.read_bytes()
            digest.update(f"{package}/{source.name}\0{len(data)}\0".encode())
            digest.update(data)
    return digest.hexdigest()
