"""The CLI's shape: commands listed, version, exit codes of usage errors, a fast --help."""

from __future__ import annotations

import subprocess
import sys

import pytest

from aslam.cli.app import main


def test_help_lists_the_three_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("record", "estimate", "report"):
        assert command in out


def test_help_lists_every_exit_code_one_to_a_line(capsys):
    """Scripts read the codes off --help; each on its own line, none missing (typer keeps the breaks)."""
    from aslam.cli import app as cli_app

    assert main(["--help"]) == 0
    lines = [line.strip(" │") for line in capsys.readouterr().out.splitlines()]
    from aslam.app.sweep import TasksFailed
    from aslam.core.errors import AslamError, QualityGateFailed

    codes = {value for name, value in vars(cli_app).items() if name.startswith("EXIT_")}
    codes |= {error.exit_code for error in (AslamError, QualityGateFailed, TasksFailed)}
    listed = {int(line.split()[0]) for line in lines if line.split() and line.split()[0].isdigit()}
    assert listed == codes


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


def test_a_command_builds_only_its_own_options():
    """typer builds every registered command's options on each start: a command registers alone."""
    code = (
        "import sys\n"
        "from aslam.cli.app import COMMAND_MODULES, main\n"
        "main(['info', '--help'])\n"
        "others = [m for m in COMMAND_MODULES.values() if m != 'info' and f'aslam.cli.{m}' in sys.modules]\n"
        "assert not others, others\n"
        "main(['--help'])\n"
        "assert all(f'aslam.cli.{m}' in sys.modules for m in COMMAND_MODULES.values())\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def test_the_console_script_flushes_everything_before_it_skips_teardown():
    """`aslam` ends with os._exit: what it printed into a pipe must all be there, with its exit code."""
    from pathlib import Path

    aslam = Path(sys.executable).with_name("aslam")
    help_text = subprocess.run([str(aslam), "estimate", "--help"], capture_output=True, text=True, timeout=60)
    assert help_text.returncode == 0
    from aslam.core.config import EstimatorConfig

    last_option = "--" + EstimatorConfig.parameters()[-1][0].replace("_", "-")  # the help's last lines
    assert "Show this message and exit." in help_text.stdout and last_option in help_text.stdout
    usage = subprocess.run(
        [str(aslam), "record", "--no-such-option"], capture_output=True, text=True, timeout=60
    )
    assert usage.returncode == 2 and usage.stderr.count("\n") == 1


def test_an_estimate_of_a_recording_loads_no_image_folder_reader(recording, tmp_path):
    """Telling an image folder from a recording needs the image folder's rule, not its reader (pose
    files, KITTI stamps, decimal): loaded at the top of the bag reader, it was 5 ms of every
    estimate's start-up, before the reader process forks."""
    code = (
        "import sys\n"
        "from aslam.cli.app import main\n"
        f"assert main(['estimate', {str(recording)!r}, '-o', {str(tmp_path / 'e.mcap')!r}, '-q']) == 0\n"
        "loaded = [m for m in ('aslam.data_formats.image_folder', 'decimal') if m in sys.modules]\n"
        "assert not loaded, loaded\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def test_every_numeric_option_reads_decimal_digits_only():
    """click's FLOAT and INT call ``float()`` and ``int()``, which take ``1_0`` (10) and the digits
    of other scripts (``٥`` is 5): every numeric option goes through ``decimal_number`` or
    ``whole_number`` instead, the generated estimator options too."""
    import typer

    from aslam.cli.app import _register_commands, app

    _register_commands()
    group = typer.main.get_command(app)
    numeric = []
    for name, command in group.commands.items():  # type: ignore[attr-defined]
        for param in command.params:
            numeric += [(name, param.name)] if param.type.name in ("float", "integer") else []
    assert numeric == []


@pytest.mark.parametrize(
    "args",
    [
        ["report", "e.mcap", "--radius-m", "0_5"],
        ["report", "e.mcap", "--heading-deg", "٤٥"],
        ["estimate", "r.mcap", "-o", "e.mcap", "--step-m", "٥"],
        ["estimate", "r.mcap", "-o", "e.mcap", "--workers", "1_0"],
        ["record", "-o", "r.mcap", "--seed", "３"],
        ["record", "-o", "r.mcap", "--size", "３２０x240"],
        ["import", "frames", "-o", "r.mcap", "--rate", "1_0"],
        ["sweep", "s.toml", "-o", "out", "--task-timeout", "1_0"],
    ],
)
def test_a_number_in_other_digits_is_refused_before_any_file_is_read(args, tmp_path, monkeypatch, capsys):
    """``report --radius-m 0_5`` scored revisits within 5 m, and ``--step-m ٥`` took keyframes 5 m
    apart, in silence; now exit 2 naming the option (no file named is even looked for)."""
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "not a decimal number" in err or "not a whole number" in err or "WIDTHxHEIGHT" in err


def test_the_workers_default_is_the_pipelines():
    """``--workers``' default is written out in the option (the pipeline's import is not for every
    command's start): it must stay the one ``aslam.app.estimate`` uses."""
    from aslam.app.pipeline import DEFAULT_WORKERS
    from aslam.cli.estimate import _FIXED

    assert _FIXED["workers"][1] == DEFAULT_WORKERS


def test_every_commands_help_shows_the_defaults_its_options_spell_out(capsys, monkeypatch):
    """An option's help that ends "[default: …]" in words must show it: rich reads an unescaped
    "[default: …]" as a markup tag and drops it (record's --laps and --fps did)."""
    import re

    import typer.main

    from aslam.cli.app import _register_commands, app

    monkeypatch.setenv("COLUMNS", "400")  # one help line an option
    _register_commands()
    commands = typer.main.get_command(app).commands.values()  # type: ignore[attr-defined]
    assert len(commands) >= 6
    for command in commands:
        spelled = [
            re.search(r"\[default: [^\]]*\]", param.help).group(0)  # type: ignore[union-attr]
            for param in command.params
            if getattr(param, "help", None) and "[default: " in param.help
        ]
        assert main([command.name, "--help"]) == 0
        out = " ".join(capsys.readouterr().out.split())
        for text in spelled:
            assert " ".join(text.split()) in out, (command.name, text)


def test_an_option_given_no_value_points_to_its_commands_help(capsys):
    """Click raises this one with the top level's context: the line said `see 'aslam --help'`."""
    assert main(["record", "--route"]) == 2
    assert capsys.readouterr().err == (
        "aslam: error: Option '--route' requires an argument. (see 'aslam record --help')\n"
    )
    assert main(["estimate", "in.mcap", "-o"]) == 2
    assert capsys.readouterr().err.endswith("(see 'aslam estimate --help')\n")
    assert main(["--no-such-option"]) == 2
    assert capsys.readouterr().err.endswith("(see 'aslam --help')\n")
