"""The fields a recording's ROS 2 schemas must declare before a message is decoded with them.

A schema's *name* says ``sensor_msgs/msg/Image``, but its *definition* is text stored in the file:
one bit flip turns ``string encoding`` into ``string encodinf`` and the decoded message no longer
has the field the reader uses. Every type the reader decodes is checked here against the fields it
reads (name and type), in its own section and in the sections of the types it nests, so such a
file is one error line naming the schema and the field instead of an AttributeError.

The definition is parsed by mcap_ros2's own splitter and ROS parser, exactly as its decoder will
parse it: a check that reads the text differently (a section header damaged so that a later
section *replaces* the schema's own definition) would pass files the decoder then misreads.
tests/test_reliability.py flips every bit of the definitions the reader decodes and checks that
each flip is either refused here, refused by the decoder, or decodes to a message with the fields.
"""

from __future__ import annotations

import contextlib
import io
from typing import Any

#: For each type (package/Type, the ``/msg/`` left out): the fields the reader uses, name → type.
USED_FIELDS: dict[str, dict[str, str]] = {
    "sensor_msgs/CompressedImage": {"header": "Header", "format": "string", "data": "uint8[]"},
    "sensor_msgs/Image": {
        "header": "Header",
        "height": "uint32",
        "width": "uint32",
        "encoding": "string",
        "step": "uint32",
        "data": "uint8[]",
    },
    "sensor_msgs/CameraInfo": {"height": "uint32", "width": "uint32", "k": "float64[9]"},
    "nav_msgs/Odometry": {"header": "Header", "pose": "PoseWithCovariance"},
    "geometry_msgs/PoseStamped": {"header": "Header", "pose": "Pose"},
    "geometry_msgs/PoseWithCovarianceStamped": {"header": "Header", "pose": "PoseWithCovariance"},
    "geometry_msgs/PoseWithCovariance": {"pose": "Pose"},
    "geometry_msgs/Pose": {"position": "Point", "orientation": "Quaternion"},
    "geometry_msgs/Point": {"x": "float64", "y": "float64"},
    "geometry_msgs/Quaternion": {"x": "float64", "y": "float64", "z": "float64", "w": "float64"},
    "std_msgs/Header": {"stamp": "Time"},
    "builtin_interfaces/Time": {"sec": "int32", "nanosec": "uint32"},
}
_ALIASES = {"byte[]": "uint8[]"}


def type_key(name: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` → ``pkg/Type``."""
    return name.replace("/msg/", "/")


def _base(type_string: str) -> str:
    """A field type without its package (``geometry_msgs/Pose`` → ``Pose``), aliases resolved."""
    type_string = _ALIASES.get(type_string, type_string)
    return type_string.rsplit("/", 1)[-1]


def _definitions(name: str, text: str) -> dict[str, dict[str, str]] | None:
    """type → {field name: field type} exactly as mcap_ros2's decoder will see them, or None if
    the text does not parse (the decoder then reports it).

    Parsed by mcap_ros2's own section splitter and ROS parser, and kept the way its decoder keeps
    them (full and short names, a later section of one name replacing an earlier one), so the
    check sees what the decoder will use.
    """
    from mcap_ros2._dynamic import _for_each_msgdef

    definitions: dict[str, dict[str, str]] = {}

    def keep(full_name: str, short_name: str, spec: Any) -> None:
        fields = {field.name: str(field.type) for field in spec.fields}
        definitions[full_name] = definitions[short_name] = fields

    try:
        with contextlib.redirect_stderr(io.StringIO()):  # the ROS parser prints before raising
            _for_each_msgdef(name, text, keep)
    except Exception:
        return None
    return definitions


def definition_problem(name: str, text: str) -> str | None:
    """Why the definition ``text`` of schema ``name`` lacks a field the reader uses (None: it does not).

    The schema's own type is checked as the decoder will take it (by its full name), the nested
    types by their short names; a type the text does not define is left to the decoder.
    """
    definitions = _definitions(name, text)
    if definitions is None:
        return None
    for section, used in USED_FIELDS.items():
        fields = definitions.get(name if section == type_key(name) else section)
        if fields is None:
            continue
        for field, wanted in used.items():
            declared = fields.get(field)
            if declared is None:
                return f"its definition of {section} has no field '{field}' ({wanted} {field})"
            if _base(declared) != _base(wanted):
                return (
                    f"its definition of {section} declares '{declared} {field}', expected '{wanted} {field}'"
                )
    return None
