"""The commands under the environments shells and CI pipelines give them: locales that cannot
encode UTF-8, narrow and wide terminals, logs that are no terminal, a read-only HOME."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest
from conftest import ASLAM

from aslam.cli.app import main


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


C_LOCALE = {"LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0"}
"""A locale whose encoding is ASCII, Python's UTF-8 mode off: file names are bytes Python spells
with surrogate escapes, and stdout cannot encode "—"."""


def test_a_non_ascii_name_read_from_a_file_is_found_under_a_c_locale(recording: Path, tmp_path: Path):
    """An estimate holds its recording's name as UTF-8 text, and a sweep file its recordings'.
    Under a C locale without UTF-8 mode the name 'café×.mcap' read back was a name no file has
    (Python spells that file 'caf\\udcc3\\udca9…'): the report went without ground truth, and the
    sweep refused a recording that is there."""
    named = tmp_path / "café×.mcap"
    named.write_bytes(recording.read_bytes())
    estimate = tmp_path / "e.mcap"
    env = {**os.environ, **C_LOCALE}

    def aslam(*args: str) -> subprocess.CompletedProcess[str]:
        done = subprocess.run([str(ASLAM), *args], capture_output=True, text=True, env=env, timeout=120)
        assert done.returncode == 0, done.stderr
        return done

    aslam("estimate", str(named), "-o", str(estimate), "-q")
    report = json.loads(aslam("report", str(estimate), "--json", "-").stdout)
    assert report["ground_truth"] is True
    sweep_file = tmp_path / "sweep.toml"
    sweep_file.write_text('[recordings]\npaths = ["café×.mcap"]\n[grid]\nbeta = 3.0\n', encoding="utf-8")
    plan = json.loads(
        aslam("sweep", str(sweep_file), "-o", str(tmp_path / "out"), "--dry-run", "--json", "-").stdout
    )
    assert plan["tasks"] == 1 and plan["cannot_write"] is None


def _latin_1_locale(folder: Path) -> dict[str, str]:
    """The environment of a Latin-1 locale (made here by localedef: few machines have one)."""
    made = folder / "locales"
    made.mkdir()
    try:
        done = subprocess.run(
            ["localedef", "-i", "en_US", "-f", "ISO-8859-1", str(made / "en_US.ISO-8859-1")],
            capture_output=True,
            timeout=60,
        )
    except FileNotFoundError:
        pytest.skip("no localedef to make a Latin-1 locale")
    if done.returncode != 0:
        pytest.skip(f"localedef made no Latin-1 locale: {done.stderr.decode(errors='replace')}")
    return {"LOCPATH": str(made), "LC_ALL": "en_US.ISO-8859-1", "LANG": "", "PYTHONUTF8": "0"}


def test_an_estimate_made_under_a_latin_1_locale_names_its_recording_for_every_locale(
    recording: Path, tmp_path: Path
):
    """Under a Latin-1 locale Python spells the file 'café.mcap' (UTF-8 bytes c3 a9) 'cafÃ©.mcap',
    and the estimate stored those two letters as UTF-8: a name no file has. Since names read back
    are taken as their UTF-8 bytes, report lost that recording even under the locale that made the
    estimate (no ground truth), where it had found it. The name is stored as its bytes: 'café'."""
    from aslam.data_formats.estimate import read_estimate

    latin_1 = _latin_1_locale(tmp_path)
    named = tmp_path / "café.mcap"
    named.write_bytes(recording.read_bytes())
    estimate = tmp_path / "e.mcap"

    def aslam(locale: dict[str, str], *args: str) -> bytes:
        done = subprocess.run(
            [str(ASLAM), *args], capture_output=True, env={**os.environ, **locale}, timeout=120
        )
        assert done.returncode == 0, done.stderr
        return done.stdout

    aslam(latin_1, "estimate", str(named), "-o", str(estimate), "-q")
    assert read_estimate(estimate).metadata.recording.path == str(named)
    for locale in (latin_1, C_LOCALE, {}):
        assert json.loads(aslam(locale, "report", str(estimate), "--json", "-", "-q"))["ground_truth"] is True


def _on_a_terminal(argv: list[str], columns: int) -> str:
    """What ``argv`` shows on a terminal ``columns`` wide (a pseudo-terminal as stdout and stderr)."""
    import pty

    leader, follower = pty.openpty()
    env = {**os.environ, "COLUMNS": str(columns), "TERM": "xterm"}
    with subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=follower, stderr=follower, env=env) as done:
        os.close(follower)
        shown = bytearray()
        while True:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # EIO: the command ended, its side of the terminal closed
                break
            if not chunk:
                break
            shown += chunk
        assert done.wait(timeout=120) == 0, shown.decode(errors="replace")
    os.close(leader)
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", shown.decode())


def test_a_narrow_terminal_cuts_no_figure_of_the_reports_tables(estimate_file: Path, tmp_path: Path):
    """On a terminal narrower than the tables, rich cut their cells to fit: at 40 columns every
    maximum error read "0.1…" and "5.2…". Now a table is as wide as its figures need, wider than
    the window if it must be (the terminal wraps the line)."""
    summary = tmp_path / "s.json"
    assert main(["report", str(estimate_file), "--json", str(summary), "-q"]) == 0
    errors = json.loads(summary.read_text())["error"]["best"]
    shown = _on_a_terminal([str(ASLAM), "report", str(estimate_file)], columns=40)
    assert "…" not in shown
    for axis in ("x_m", "y_m", "heading_deg"):
        assert f"{errors[axis]['max']:.3f}" in shown


def test_the_estimate_progress_line_fits_an_80_column_terminal(recording: Path, tmp_path: Path):
    """On the commonest terminal width rich cut the progress line's own figures: "115… images"
    for 115/181 and "0:0…" for the time elapsed."""
    shown = _on_a_terminal(
        [str(ASLAM), "estimate", str(recording), "-o", str(tmp_path / "e.mcap")], columns=80
    )
    lines = re.split(r"[\r\n]", shown)
    progress = [line for line in lines if line.startswith(("estimate ", "writing ", "pose graph "))]
    assert progress, shown
    assert not [line for line in progress if "…" in line]
    # Once every image is read, the line says the map is being written: the pose graph's iterations
    # as GTSAM optimises it (it holds the interpreter: nothing else can move the line), then the file.
    figures = r" .* (\d+)/\1 images · \d+ kf · \d+ hyp · \d+ kf/s \d+:\d\d:\d\d"
    assert re.search(r"^pose graph \d+" + figures, "\n".join(progress), re.MULTILINE)
    assert re.search(r"^writing" + figures, progress[-1])


@pytest.mark.parametrize("images", [181, 100_000, 1_000_000, 10_000_000])
def test_the_estimate_progress_line_keeps_its_figures_at_millions_of_images(images: int):
    """The line fitted 80 columns at 100,000 images; at a million, every image a keyframe and 50
    hypotheses (the default bound), rich shrank the image count first: "1000000/1000… images"."""
    import io

    from rich.console import Console
    from rich.progress import Progress

    from aslam.cli.estimate import progress_columns

    console = Console(width=80, file=io.StringIO(), force_terminal=True, color_system=None)
    progress = Progress(*progress_columns(), console=console)
    progress.add_task("estimate", total=images, completed=images, keyframes=images, hypotheses=50, rate=1234)
    console.print(progress.get_renderable())
    line = console.file.getvalue().rstrip("\n")
    assert "…" not in line
    assert f" {images}/{images} images · {images} kf · 50 hyp · 1234 kf/s 0:00:00" in line


WINDOWS_TEXT = {"bom": "\ufeff{}", "crlf": "{}", "bom+crlf": "\ufeff{}"}
"""How a Windows editor saves a file: a UTF-8 byte-order mark first, CRLF line ends, or both."""


@pytest.mark.parametrize("saved", WINDOWS_TEXT)
def test_config_sweep_and_route_files_from_a_windows_editor_are_read(
    recording: Path, tmp_path: Path, capsys, saved: str
):
    """A byte-order mark was refused: a config or sweep file as "not valid TOML (Invalid statement
    (at line 1, column 1))", a route file as "Unexpected UTF-8 BOM"; pose files skipped it."""

    def write(name: str, text: str) -> Path:
        path = tmp_path / name
        newline = "\r\n" if "crlf" in saved else "\n"
        path.write_bytes(WINDOWS_TEXT[saved].format(text).replace("\n", newline).encode())
        return path

    config = write("c.toml", "[estimator]\nbeta = 2.5\n")
    assert (
        main(["estimate", str(recording), "-o", str(tmp_path / "e.mcap"), "--config", str(config), "-q"]) == 0
    )
    sweep_file = write("s.toml", f'[recordings]\npaths = ["{recording}"]\n[grid]\nbeta = 3.0\n')
    assert main(["sweep", str(sweep_file), "-o", str(tmp_path / "out"), "--dry-run", "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["tasks"] == 1
    route = write(
        "r.json", '{\n "start": {"x_m": 0, "y_m": 0, "yaw_deg": 0},\n "actions": [{"forward_m": 1}]\n}\n'
    )
    assert (
        main(["record", "--route", str(route), "--size", "32x24", "-o", str(tmp_path / "r.mcap"), "-q"]) == 0
    )


def test_json_documents_name_a_file_the_same_under_a_utf8_and_a_c_locale(recording: Path, tmp_path: Path):
    """Under a C locale without UTF-8 mode a name's bytes above 127 reached the JSON documents as
    surrogates, ``"caf\\udcc3\\udca9\\udcc3\\udc97.mcap"`` where a UTF-8 locale wrote
    ``"caf\\u00e9\\u00d7.mcap"``: the same command gave other bytes, and a JSON reader other than
    Python's (jq) no name. A byte that is not UTF-8 is still the surrogate of that byte."""
    for name in ("café×.mcap", os.fsdecode(b"\xff.mcap")):
        named = tmp_path / name
        named.write_bytes(recording.read_bytes())
        documents = []
        for locale in ({}, C_LOCALE):
            argv = [str(ASLAM), "info", str(named), "--json", "-"]
            done = subprocess.run(argv, capture_output=True, env={**os.environ, **locale}, timeout=120)
            assert done.returncode == 0, done.stderr
            documents.append(done.stdout)
        assert documents[0] == documents[1]
        assert json.loads(documents[1])["path"] == str(named)
