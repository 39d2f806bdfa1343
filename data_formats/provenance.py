"""Which aslam wrote a file: the version stamped into recordings and estimate files, and the code
version a cache of computed results is keyed by.

The one place the version is written down: ``pyproject.toml`` reads it from here
(``[tool.setuptools.dynamic]``), so asking costs nothing. Looking it up in the installed
package's metadata instead (``importlib.metadata``) took 25 ms of every estimate's start-up.
"""

import functools
import hashlib
import sys
from pathlib import Path

VERSION = "0.1.0"
#: The subpackages whose code decides a render's bytes and an estimate's and a score's figures (the
#: CLI's texts decide none).
RESULT_PACKAGES = ("app", "core", "data_formats", "recorder")
#: A module's source, or its bytecode where an install ships that alone (``__pycache__`` is not read).
MODULE_SUFFIXES = (".py", ".pyc")
#: The installed distributions whose arithmetic or decoding enters a render's pixels or an estimate's
#: or a score's figures: a new numpy alone moved the last digits of ``report --json``'s errors. The
#: containers (mcap, rosbags, lz4, zstandard) give back the bytes stored, and the terminal, table
#: and cluster libraries (rich, pyarrow, dask) compute no figure: none of them counts.
RESULT_LIBRARIES = (
    "numpy",
    "opencv-python-headless",  # JPEG and raw-image decoding, resizing, features
    "imagecodecs",  # PNG decoding
    "faiss-cpu",  # the place index beyond 2,048 places
    "gtsam",  # the metric view's optimisation
    "evo",  # APE, RPE and their alignment
    "scipy",  # evo's rotations
    "pyrender",  # the recorder's rasterising
    "trimesh",  # a world file's meshes
    "pillow",  # a world file's textures, through trimesh
)


def tool_version() -> str:
    return VERSION


def code_version() -> str:
    """``VERSION+src.`` and the first 12 hex digits of a SHA-256 of the source of ``RESULT_PACKAGES``
    and of :func:`library_versions`: what a sweep's cached renders and task results are keyed by.
    VERSION alone stayed 0.1.0 through every change of the recorder, the estimator and the scoring,
    so a sweep folder kept across an upgrade had its old results reused as the new code's; and the
    source alone stayed the same through ``pip install -U numpy``, so a resumed sweep mixed results
    of two numpy versions in one table."""
    return f"{VERSION}+src.{_code_sha256()[:12]}"


@functools.cache
def library_versions() -> dict[str, str]:
    """Python's version (3.12 changed how ``sum()`` adds floats, as the recorder does a route's
    length) and each of ``RESULT_LIBRARIES``' installed one (``-`` where it is not), read from their
    metadata: none of them is imported (8 ms, once, and 25 ms for ``importlib.metadata`` where
    nothing has imported it yet)."""
    from importlib.metadata import PackageNotFoundError, version

    versions = {"python": ".".join(map(str, sys.version_info[:3]))}
    for library in RESULT_LIBRARIES:
        try:
            versions[library] = version(library)
        except PackageNotFoundError:
            versions[library] = "-"
    return versions


@functools.cache
def _code_sha256() -> str:
    """SHA-256 of every module file of ``RESULT_PACKAGES``, by name and bytes, then of
    :func:`library_versions` (a few ms, once). The module files are the
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
    for library, installed in library_versions().items():
        digest.update(f"{library}\0{installed}\0".encode())
    return digest.hexdigest()
