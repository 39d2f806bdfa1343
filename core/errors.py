"""One exception root for the whole tool, mapped to exit codes once, at the CLI edge."""

from __future__ import annotations

from pathlib import Path


class AslamError(Exception):
    """Root of every error the tool raises on purpose; `exit_code` is what the CLI exits with."""

    exit_code = 2

    def __init__(self, problem: str, *, path: Path | str | None = None) -> None:
        self.problem = problem
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


def one_line(message: str) -> str:
    """``message`` as one line of plain text: whitespace runs made one space, and every other
    control character (an escape sequence in a bag's frame name, say) shown as its code, never
    sent to a terminal to act on. How every error and warning is shown, on stderr or in a table."""
    text = " ".join(message.split())
    return "".join(ch if ch.isprintable() else f"\\x{ord(ch):02x}" for ch in text)


class InputError(AslamError):
    """A file, a value or an option that cannot be used (exit 2)."""


class ConfigError(InputError):
    """A bad configuration value or file (exit 2)."""


class QualityGateFailed(AslamError):
    """A `report --fail-on` condition held (exit 1)."""

    exit_code = 1
