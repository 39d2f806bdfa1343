"""The commands under the environments shells and CI pipelines give them: locales that cannot
encode UTF-8, narrow and wide terminals, logs that are no terminal, a read-only HOME."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from conftest import ASLAM


def test_a_read_only_home_adds_no_line_and_leaves_no_folder_behind(estimate_file: Path, tmp_path: Path):
    """matplotlib, finding no writable config folder (a read-only HOME in a CI
    container), logged two lines through Python's last-resort handler, --quiet or not, and made a
    cache folder in TMPDIR that the exit without teardown never removed: one per report."""
    home = tmp_path / "home"
    home.write_text("a file: nothing can be made under it")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = {
        k: v for k, v in os.environ.items() if k not in ("MPLCONFIGDIR", "XDG_CONFIG_HOME", "XDG_CACHE_HOME")
    }
    env.update(HOME=str(home), TMPDIR=str(temporary))
    argv = [str(ASLAM), "report", str(estimate_file), "--plots", str(tmp_path / "plots"), "-q"]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert sorted(p.name for p in (tmp_path / "plots").iterdir())[0] == "errors.png"
    assert list(temporary.iterdir()) == []
