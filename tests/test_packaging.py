"""What a user's install holds: every module, no data file left behind, every import declared.

The Makefile's editable install maps whole folders and runs in a venv that has every package any
dependency brings, so a subpackage missing from pyproject's list, a data file beside the modules
or an import of a package only a dependency pulls in would work here and fail for a user of the
wheel (``pip install aslam-*.whl``, ``pip install .``). These checks read pyproject.toml and the
sources; they build nothing.
"""

from __future__ import annotations

import ast
import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from aslam.cli.app import main

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]
PACKAGE_DIRS = {name: (ROOT / folder).resolve() for name, folder in SETUPTOOLS["package-dir"].items()}


def _package_files(name: str) -> list[Path]:
    """The files of package ``name`` as the wheel would take them: its folder's, and its
    subfolders' unless they are packages of their own (the root, ``aslam``, holds the others)."""
    folder = PACKAGE_DIRS[name]
    inner = {path for path in PACKAGE_DIRS.values() if folder in path.parents}
    if name == "aslam":  # the repository root: its own files only (tests/, docs/ ... are not in it)
        return [path for path in folder.iterdir() if path.is_file() and not path.name.startswith(".")]
    files = []
    for path in folder.rglob("*"):
        if path.is_file() and "__pycache__" not in path.parts and not inner & set(path.parents):
            files.append(path)
    return files


def _modules() -> list[Path]:
    return [path for name in PACKAGE_DIRS for path in _package_files(name) if path.suffix == ".py"]


def test_every_package_folder_is_listed_and_mapped():
    """setuptools' ``packages`` list is explicit: a new subfolder of modules (core/index/) would be
    imported from the source tree here and missing from the wheel."""
    assert sorted(SETUPTOOLS["packages"]) == sorted(PACKAGE_DIRS)
    for name, folder in PACKAGE_DIRS.items():
        assert folder.is_dir(), f"{name} maps to {folder}, which is not a folder"
        if name != "aslam":
            assert (folder / "__init__.py").is_file(), f"{folder} has no __init__.py"
    top_level = {path.parent.resolve() for path in ROOT.glob("*/__init__.py")}
    nested = {path.parent for path in _modules() if path.parent != ROOT}
    for folder in sorted(top_level | nested):
        assert folder in PACKAGE_DIRS.values(), f"{folder} holds modules but is no package in pyproject.toml"


def test_packages_hold_modules_and_the_package_data_declared():
    """Package data is named file by file (``include-package-data = false``: with the repository
    root a package folder, it would be every file of the sdist), so a JSON schema, template or font
    read beside the modules and not in ``[tool.setuptools.package-data]`` would be absent from the
    wheel; a name declared there that matches no file would ship nothing."""
    assert SETUPTOOLS.get("include-package-data") is False
    declared = {
        (PACKAGE_DIRS[name] / file).relative_to(ROOT)
        for name, files in SETUPTOOLS.get("package-data", {}).items()
        for file in files
    }
    data = {
        path.relative_to(ROOT)
        for name in PACKAGE_DIRS
        for path in _package_files(name)
        if path.suffix != ".py"
        # the root's README, Makefile ... are the sdist's, not the package's: its marker alone is
        and (name != "aslam" or path.name == "py.typed")
    }
    assert data == declared
    markers = {(folder / "py.typed").relative_to(ROOT) for folder in PACKAGE_DIRS.values()}
    assert declared == {Path("app/sweep_example.toml"), *markers}  # `aslam sweep --example`; PEP 561


def _imported_top_level_names() -> set[str]:
    names: set[str] = set()
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    # _typeshed: the type checkers' part of the standard library, imported under TYPE_CHECKING only.
    return names - set(sys.stdlib_module_names) - {"aslam", "__future__", "_typeshed"}


def _declared_distributions() -> set[str]:
    """``[project] dependencies`` with what their extras (``dask[distributed]``) bring."""
    declared: set[str] = set()
    for text in PYPROJECT["project"]["dependencies"]:
        requirement = Requirement(text)
        declared.add(canonicalize_name(requirement.name))
        for extra in requirement.extras:
            for needed in importlib.metadata.requires(requirement.name) or []:
                sub = Requirement(needed)
                marker = sub.marker  # the extra's own requirements, not those every install has
                if marker and marker.evaluate({"extra": extra}) and not marker.evaluate({"extra": ""}):
                    declared.add(canonicalize_name(sub.name))
    return declared


def test_every_imported_package_is_a_declared_dependency():
    """A package imported but only brought by another dependency (protobuf by the Foxglove schemas,
    ruamel.yaml by rosbags) goes the day that dependency stops needing it."""
    providers = importlib.metadata.packages_distributions()
    declared = _declared_distributions()
    undeclared = {}
    for name in sorted(_imported_top_level_names()):
        distributions = {canonicalize_name(dist) for dist in providers.get(name, [])}
        if not distributions & declared:
            undeclared[name] = sorted(distributions) or "not installed"
    assert undeclared == {}


def test_every_declared_dependency_is_imported():
    providers = importlib.metadata.packages_distributions()
    imported = {
        canonicalize_name(dist) for name in _imported_top_level_names() for dist in providers.get(name, [])
    }
    direct = {canonicalize_name(Requirement(text).name) for text in PYPROJECT["project"]["dependencies"]}
    assert direct - imported == set()


def test_every_make_target_that_runs_aslam_checks_the_pyopengl_pin(tmp_path):
    """pip puts pyrender's PyOpenGL 3.1.0 back whenever it installs aslam's dependencies again; after
    a `pip install -e .` by hand the venv's sentinel files are still newer than pyproject.toml, so
    `make test` (demo, bench, fuzz) ran on 3.1.0, whose OSMesa binding is too old. Each target now
    checks the version first (``make -n`` lists the commands it would run)."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").touch()
    for sentinel in (".installed", ".dev-installed", ".bench-installed"):
        (venv / sentinel).touch()
    for target in ("demo", "test", "bench", "fuzz"):
        plan = subprocess.run(
            ["make", "-n", "-C", str(ROOT), f"VENV={venv}", target],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        assert "pip install -q --no-deps 'PyOpenGL==3.1.10'" in plan, target
        assert "m.version('PyOpenGL') != '3.1.10'" in plan, target


def _make(folder: Path, *arguments: str, path: str | None = None) -> subprocess.CompletedProcess[str]:
    """``make`` run in ``folder`` as a user would start it: no PYTHON but the arguments' (a make
    running this suite passes its own command line down in MAKEFLAGS)."""
    skip = {"PYTHON", "MAKEFLAGS", "MFLAGS", "MAKELEVEL"}
    env = {key: value for key, value in os.environ.items() if key not in skip}
    if path is not None:
        env["PATH"] = path
    return subprocess.run(
        ["make", "-C", str(folder), *arguments], capture_output=True, text=True, env=env, timeout=120
    )


def test_a_python_below_requires_python_is_refused_before_any_venv_is_made(tmp_path):
    """A PYTHON below requires-python made the venv, upgraded its pip and only then had pip refuse
    aslam; the half-made venv stayed and every later `make`, whatever PYTHON it was given, reused
    it. The floor is read from pyproject.toml (raised here above this Python)."""
    shutil.copy(ROOT / "Makefile", tmp_path)
    floor = f"{sys.version_info.major}.{sys.version_info.minor + 1}"
    text = (ROOT / "pyproject.toml").read_text()
    (tmp_path / "pyproject.toml").write_text(
        text.replace('requires-python = ">=3.11"', f'requires-python = ">={floor}"')
    )
    venv = tmp_path / "venv"
    done = _make(tmp_path, "lint", f"PYTHON={sys.executable}", f"VENV={venv}")
    have = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert done.returncode == 2
    assert done.stderr.startswith(f"aslam needs Python >= {floor}; PYTHON={sys.executable} is {have}\n")
    assert not venv.exists()


def test_a_python_given_to_a_venv_of_another_version_is_refused(tmp_path):
    """The venv is made once: `make test PYTHON=python3.12` over a venv of 3.11 ran 3.11 in
    silence. A PYTHON given must be the venv's X.Y; the Makefile's default (python3) is not checked,
    so a venv outliving a change of the system's python3 goes on."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").touch()
    for sentinel in (".installed", ".dev-installed"):
        (venv / sentinel).touch()
    other = f"{sys.version_info.major}.{sys.version_info.minor - 1}.13"
    (venv / "pyvenv.cfg").write_text(f"home = /usr/bin\nversion = {other}\n")
    done = _make(ROOT, "lint", f"PYTHON={sys.executable}", f"VENV={venv}")
    have = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert done.returncode == 2
    assert done.stderr.startswith(
        f"{venv} was made with Python {other}, not PYTHON={sys.executable} ({have}):"
    )
    assert "/bin/ruff" not in done.stdout  # nothing ran in the venv

    python3 = tmp_path / "path" / "python3"  # the default PYTHON, found on PATH
    python3.parent.mkdir()
    python3.symlink_to(sys.executable)
    path = f"{python3.parent}{os.pathsep}{os.environ['PATH']}"
    assert _make(ROOT, "check-python", f"VENV={venv}", path=path).returncode == 0
    (venv / "pyvenv.cfg").write_text(f"home = /usr/bin\nversion = {have}.1\n")
    assert _make(ROOT, "check-python", f"PYTHON={sys.executable}", f"VENV={venv}").returncode == 0


def test_make_lint_type_checks_a_clone_in_a_folder_with_a_space_and_a_venv_inside_it(tmp_path):
    """mypy ran as ``-p aslam`` from a link in the venv to the clone, the clone's path unquoted: a
    clone under "my projects" made ``ln`` fail (and ``mkdir -p`` make a folder of each word), and a
    venv in the clone named as a package may be (``VENV=venv312``, as the README suggests) led mypy
    back through the link for ever. A skeleton of the package (pyproject's subpackages, one type
    error) with such a venv, lent this one's packages: mypy names that error, then passes."""
    clone = tmp_path / "my projects" / "clone"
    clone.mkdir(parents=True)
    for name in ("Makefile", "pyproject.toml", "__main__.py"):
        shutil.copy(ROOT / name, clone)
    for package in SETUPTOOLS["packages"][1:]:
        folder = clone / package.removeprefix("aslam.")
        folder.mkdir()
        (folder / "__init__.py").write_text("")
    (clone / "cli" / "entry.py").write_text("def run() -> None:\n    pass\n")  # what __main__ runs
    (clone / "core" / "__init__.py").write_text('steps: int = "three"\n')
    venv = clone / "venv312"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = Path(sysconfig.get_paths()["purelib"])
    for lent in venv.glob("lib/python*/site-packages"):
        (lent / "lent.pth").write_text(f"{purelib}\n")
    (venv / "bin" / "ruff").symlink_to(Path(sys.executable).with_name("ruff"))
    for sentinel in (".installed", ".dev-installed"):
        (venv / sentinel).touch()

    failed = _make(clone, "lint", f"PYTHON={sys.executable}", "VENV=venv312")
    assert failed.returncode == 2, failed.stderr
    assert 'aslam/core/__init__.py:1: error: Incompatible types in assignment (expression has type "str"' in (
        failed.stdout
    )
    assert "Found 1 error in 1 file (checked 7 source files)" in failed.stdout
    assert [path.name for path in tmp_path.iterdir()] == ["my projects"]
    (clone / "core" / "__init__.py").write_text("steps: int = 3\n")
    passed = _make(clone, "lint", f"PYTHON={sys.executable}", "VENV=venv312")
    assert passed.returncode == 0, passed.stdout + passed.stderr
    assert "Success: no issues found in 7 source files" in passed.stdout


def test_python_dash_m_aslam_is_the_console_script(capsys):
    """``python -m aslam`` (__main__.py at the root, installed as aslam/__main__.py) for an
    interpreter whose scripts folder is not on PATH."""
    assert main(["--version"]) == 0
    expected = capsys.readouterr().out
    done = subprocess.run(
        [sys.executable, "-m", "aslam", "--version"], capture_output=True, text=True, timeout=60
    )
    assert (done.returncode, done.stdout, done.stderr) == (0, expected, "")
