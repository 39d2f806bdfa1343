"""`aslam record` (skeleton; filled in by its issue)."""

from __future__ import annotations

from aslam.cli.app import app


@app.command()
def record() -> None:
    """Not implemented yet."""
    raise NotImplementedError("record")
