"""Which aslam wrote a file: the version stamped into recordings and estimate files."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version


def tool_version() -> str:
    try:
        return version("aslam")
    except PackageNotFoundError:  # running from a source tree without an install
        return "0+unknown"
