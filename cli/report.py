"""`aslam report` (skeleton; filled in by its issue)."""

from __future__ import annotations

from aslam.cli.app import app


@app.command()
def report() -> None:
    """Not implemented yet."""
    raise NotImplementedError("report")
