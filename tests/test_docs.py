"""Docs that are generated from code stay equal to it."""

from __future__ import annotations

from pathlib import Path

from aslam.app.config_file import estimator_options_markdown

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_usage_lists_every_estimator_parameter_with_its_current_default():
    table = estimator_options_markdown()
    assert table in (DOCS / "usage.md").read_text(), (
        "docs/usage.md's estimator table is stale; replace it with:\n" + table
    )
