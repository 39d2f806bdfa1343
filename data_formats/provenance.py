"""Which aslam wrote a file: the version stamped into recordings and estimate files.

The one place the version is written down: ``pyproject.toml`` reads it from here
(``[tool.setuptools.dynamic]``), so asking costs nothing. Looking it up in the installed
package's metadata instead (``importlib.metadata``) took 25 ms of every estimate's start-up.
"""

VERSION = "0.1.0"


def tool_version() -> str:
    return VERSION
