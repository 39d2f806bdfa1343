"""``python -m aslam``: the ``aslam`` console script, for an interpreter whose scripts folder is not
on PATH (``pip install --user``, a venv not activated). The repository root is the ``aslam``
package (pyproject.toml's package-dir), so this file installs as ``aslam/__main__.py``."""

from aslam.cli.entry import run

if __name__ == "__main__":
    run()
