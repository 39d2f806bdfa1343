"""Docs that are generated from the code, or list what it offers, stay equal to it."""

from __future__ import annotations

import re
from pathlib import Path

from aslam.app.config_file import estimator_options_markdown

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_usage_lists_every_estimator_parameter_with_its_current_default():
    table = estimator_options_markdown()
    assert table in (DOCS / "usage.md").read_text(), (
        "docs/usage.md's estimator table is stale; replace it with:\n" + table
    )


#: Where each command's options are described, one row each.
OPTIONS_DOCUMENTED_IN = {
    "record": "recorder.md",
    "import": "usage.md",
    "info": "usage.md",
    "estimate": "usage.md",
    "report": "usage.md",
    "sweep": "sweep.md",
}


def test_every_option_of_every_command_is_in_its_document():
    """An option added to a command and not to its document is caught here, not by a user reading
    ``--help`` beside the docs (``estimate --map``, ``import``'s and ``info``'s options were missing)."""
    import typer

    from aslam.cli.app import COMMAND_MODULES, _register_commands, app

    _register_commands()
    commands = typer.main.get_command(app).commands
    assert set(OPTIONS_DOCUMENTED_IN) == set(COMMAND_MODULES)
    missing = [
        f"{name} {option} ({document})"
        for name, document in OPTIONS_DOCUMENTED_IN.items()
        for parameter in commands[name].params
        for option in parameter.opts
        if option.startswith("--")
        and option != "--help"
        # in the first cell of a table row: `--rate HZ`, `-o, --output FILE`, `-q`, `--quiet` / …
        and not re.search(rf"^\| `[^|\n]*{re.escape(option)}(?![\w-])", (DOCS / document).read_text(), re.M)
    ]
    assert missing == [], missing


def python_example(document: str, heading: str) -> str:
    """The first ```python block under ``heading`` in ``docs/<document>``."""
    text = (DOCS / document).read_text()
    section = text[text.index(f"\n{heading}\n") :]
    start = section.index("```python\n") + len("```python\n")
    return section[start : section.index("```\n", start)]


def test_the_python_examples_run_as_written(tmp_path, monkeypatch, capsys):
    """architecture.md's "From Python" (record, estimate, score, a gate, an error) and recorder.md's
    Python API, run as a user pastes them; the estimate its EstimatorConfig made has the bytes of
    the command with the same option."""
    from aslam.cli.app import main

    monkeypatch.chdir(tmp_path)
    exec(compile(python_example("recorder.md", "## Python API"), "recorder.md", "exec"), {})
    assert Path("x.mcap").stat().st_size > 0
    exec(compile(python_example("architecture.md", "## From Python"), "architecture.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    keyframes, precision, heard = printed[0].split(" ", 2)
    assert int(keyframes) > 60 and float(precision) > 0.9 and heard == "[]"
    assert printed[1] == "[]"
    assert printed[2] == (
        "EstimateError run.mcap not an aslam estimate file"
        " (no 'aslam.estimate' metadata; is it a recording?) 2"
    )
    assert (
        main(["estimate", "run.mcap", "-o", "cli.est.mcap", "--thumbnail-beta", "6", "--no-timing", "-q"])
        == 0
    )
    assert Path("cli.est.mcap").read_bytes() == Path("run.est.mcap").read_bytes()


def test_architecture_names_every_module_and_data_file():
    """docs/architecture.md's "Modules" table has a row for each module and each package data file,
    and none for a module that is gone."""
    root = DOCS.parent
    files = {"__main__.py"} | {
        str(path.relative_to(root))
        for folder in ("app", "cli", "core", "data_formats", "recorder")
        for path in (root / folder).iterdir()
        if path.suffix in {".py", ".toml"} and path.name != "__init__.py"
    }
    text = (DOCS / "architecture.md").read_text()
    section = text[text.index("\n## Modules\n") : text.index("\n## From Python\n")]
    rows = set(re.findall(r"^\| `([^`]+)` \|", section, re.M))
    assert rows == files


def test_every_observation_model_is_described_in_the_option_help_and_estimator_md():
    """A model registered in OBSERVATION_MODELS and not described was accepted by
    ``--observation-model`` while ``--help`` and usage.md's table named only the others."""
    from aslam.core.config import EstimatorConfig
    from aslam.core.observation import OBSERVATION_MODELS

    help_text = next(text for name, _, _, text in EstimatorConfig.parameters() if name == "observation_model")
    estimator_md = (DOCS / "estimator.md").read_text()
    undescribed = [
        name
        for name in OBSERVATION_MODELS
        if f"'{name}'" not in help_text or not re.search(rf"^### `{re.escape(name)}`", estimator_md, re.M)
    ]
    assert undescribed == []


def test_every_route_preset_is_in_the_route_help_and_recorder_md():
    """A preset is one entry of ``recorder.routes.PRESETS``; ``record --route``'s help and
    recorder.md's table of presets, written by hand, name each one."""
    import typer

    from aslam.cli.app import _register_commands, app
    from aslam.recorder.routes import PRESETS

    _register_commands()
    record = typer.main.get_command(app).commands["record"]
    route_help = next(parameter for parameter in record.params if parameter.name == "route").help or ""
    recorder_md = (DOCS / "recorder.md").read_text()
    undescribed = [
        name
        for name in PRESETS
        if not re.search(rf"\b{re.escape(name)}\b", route_help)
        or not re.search(rf"^\| `{re.escape(name)}` \|", recorder_md, re.M)
    ]
    assert undescribed == []


def test_every_pose_file_format_is_in_usage_md_and_real_data_md():
    """A format is one ``PoseFormat`` and its ``pose_files.LAYOUTS`` entry; ``import --format``'s row in
    usage.md and real-data.md's table of pose files, written by hand, name each one."""
    from aslam.data_formats.format_names import PoseFormat

    usage_row = re.search(r"^\| `--format ([^`]*)` \|", (DOCS / "usage.md").read_text(), re.M)
    assert usage_row is not None
    real_data = (DOCS / "real-data.md").read_text()
    undescribed = [
        fmt.value
        for fmt in PoseFormat
        if fmt.value not in usage_row[1].split("\\|")
        or not re.search(rf"^  \| {fmt.value.upper()} \|", real_data, re.M)
    ]
    assert undescribed == []
