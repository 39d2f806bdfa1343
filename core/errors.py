"""One exception root for the whole tool, mapped to exit codes once, at the CLI edge."""

from __future__ import annotations

from pathlib import Path


class AslamError(Exception):
    """Root of every error the tool raises on purpose; `exit_code` is what the CLI exits with."""

    exit_code = 2

    def __init__(self, problem: str, *, path: Path | str | None = None) -> None:
        self.problem = problem
        self.path = None if path is None else str(path)
        super().__init__(f"{printable(self.path)}: {problem}" if self.path else problem)


def printable(text: str) -> str:
    """``text`` with every character a terminal would act on or cannot show written as its Python
    escape (``\\n``, ``\\t``, ``\\x1b``, ``\\udcff`` for an undecodable byte); text without one is
    returned as it is. How a file name is shown: a newline in it never makes two lines, an escape
    never recolours the terminal, and the name stays exact (not a space for a newline)."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)


def one_line(message: str) -> str:
    """``message`` as one line of plain text: whitespace runs made one space, and every other
    control character (an escape sequence in a bag's frame name, say) shown as its escape
    (:func:`printable`), never sent to a terminal to act on. How every error and warning is shown,
    on stderr or in a table; the file an error names is :func:`printable` already, so a newline in
    its name stays ``\\n``."""
    return printable(" ".join(message.split()))


class InputError(AslamError):
    """A file, a value or an option that cannot be used (exit 2)."""


class ConfigError(InputError):
    """A bad configuration value or file (exit 2)."""


class QualityGateFailed(AslamError):
    """A `report --fail-on` condition held (exit 1)."""

    exit_code = 1
