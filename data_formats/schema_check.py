"""The fields a recording's ROS 2 schemas must declare before a message is decoded with them.

A schema's *name* says ``sensor_msgs/msg/Image``, but its *definition* is text stored in the file:
one bit flip turns ``string encoding`` into ``string encodinf`` and the decoded message no longer
has the field the reader uses. Every type the reader decodes is checked here against the fields it
reads (name and type), in its own section and in the sections of the types it nests, so such a
file is one error line naming the schema and the field instead of an AttributeError.
"""

from __future__ import annotations

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
_SEPARATOR = "=" * 80
_ALIASES = {"byte[]": "uint8[]"}


def type_key(name: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` → ``pkg/Type``."""
    return name.replace("/msg/", "/")


def _base(type_string: str) -> str:
    """A field type without its package (``geometry_msgs/Pose`` → ``Pose``), aliases resolved."""
    type_string = _ALIASES.get(type_string, type_string)
    return type_string.rsplit("/", 1)[-1]


def _sections(name: str, text: str) -> dict[str, dict[str, str]]:
    """Each section of a concatenated definition: type → {field name: field type}."""
    sections: dict[str, dict[str, str]] = {}
    current = type_key(name)
    fields: dict[str, str] = {}
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("=" * 10):
            sections.setdefault(current, fields)
            current, fields = "", {}
            continue
        if line.startswith("MSG:"):
            current = type_key(line[4:].strip())
            continue
        type_string, _, rest = line.partition(" ")
        rest = rest.strip()
        if not rest or "=" in rest:
            continue  # a constant (TYPE NAME=VALUE) or a line the ROS parser refuses itself
        fields.setdefault(rest.split()[0], type_string)
    sections.setdefault(current, fields)
    return sections


def definition_problem(name: str, text: str) -> str | None:
    """Why the definition ``text`` of schema ``name`` lacks a field the reader uses (None: it does not).

    Types the reader does not decode, and sections absent from ``text`` (the ROS parser reports
    those), are not checked here.
    """
    sections = _sections(name, text)
    for section, fields in sections.items():
        used = USED_FIELDS.get(section)
        if used is None:
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
