"""The CLI's shape: commands listed, version, exit codes of usage errors, a fast --help."""

from __future__ import annotations

import subprocess
import sys

from aslam.cli.app import main


def test_help_lists_the_three_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("record", "estimate", "report"):
        assert command in out


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("aslam ")


def test_unknown_option_is_one_line_exit_2(capsys):
    assert main(["record", "--no-such-option"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no-such-option" in err


def test_help_does_not_import_heavy_modules():
    code = (
        "import sys\n"
        "from aslam.cli.app import main\n"
        "main(['--help'])\n"
        "heavy = [m for m in ('pyrender', 'cv2', 'matplotlib', 'OpenGL') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
