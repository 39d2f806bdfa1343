"""Errors of the recorder: every one is an :class:`~aslam.core.errors.InputError` (exit 2)."""

from __future__ import annotations

from aslam.core.errors import InputError


class RouteError(InputError):
    """A route file or preset that cannot be driven (bad JSON, bad action, open route with laps)."""


class WorldError(InputError):
    """A scene file that cannot be loaded, or a route that does not stay in its free space."""


class RenderError(InputError):
    """No headless OpenGL platform could be started (EGL and OSMesa both failed)."""
