"""`aslam estimate` (skeleton; filled in by its issue)."""

from __future__ import annotations

from aslam.cli.app import app


@app.command()
def estimate() -> None:
    """Not implemented yet."""
    raise NotImplementedError("estimate")
