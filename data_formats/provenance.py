"""Which aslam wrote a file: the version stamped into recordings and estimate files."""

from __future__ import annotations


def tool_version() -> str:
    from importlib.metadata import PackageNotFoundError, version  # slow to import: only when asked

    try:
        return version("aslam")
    except PackageNotFoundError:  # running from a source tree without an install
        return "0+unknown"
