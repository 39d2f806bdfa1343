"""Estimate files: what ``aslam estimate`` found, as MCAP with JSON messages (``docs/formats.md``).

* metadata ``aslam.estimate``: tool version, the estimator configuration, the recording's identity
  (absolute path, size, SHA-256) and the topics read;
* metadata ``aslam.timing`` (optional): wall-clock figures, the only non-deterministic part;
* ``/aslam/keyframe``: one message per keyframe, the hypotheses after it (best first);
* ``/aslam/graph``: one message at the end, the best hypothesis's map and the final hypotheses.

Every channel has a JSON Schema, so Foxglove and ``mcap cat --json`` can read the file without
this package. ``EstimateWriter`` writes under a temporary name and renames when complete;
``iter_keyframes`` streams the keyframes back and ``read_estimate`` returns the rest as the core's
own types (``MapState``, ``MapLink``, ``Hypothesis``, ``TreeStats``). Each takes a path or a file
``open_estimate`` opened: a reader that reads a file in several passes opens it once, so every
pass reads the same file even when another process replaces it meanwhile (``estimate --force``).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import re
from collections.abc import Generator, Iterator, Mapping
from contextlib import closing
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from aslam.core.estimator import EstimateResult, MapLink, MapState, StepResult
from aslam.core.tree import Hypothesis, TreeStats
from aslam.data_formats import files
from aslam.data_formats.errors import EstimateError
from aslam.data_formats.mcap_file import McapFile

if TYPE_CHECKING:
    from aslam.data_formats.foxglove import MetricScene

ESTIMATE_METADATA = "aslam.estimate"
TIMING_METADATA = "aslam.timing"
KEYFRAME_TOPIC = "/aslam/keyframe"
GRAPH_TOPIC = "/aslam/graph"
PLACE_VIEWS_TOPIC = "/aslam/place_views"
KEYFRAME_SCHEMA_NAME = "aslam.Keyframe"
GRAPH_SCHEMA_NAME = "aslam.Graph"
PLACE_VIEWS_SCHEMA_NAME = "aslam.PlaceViews"
PLACES_PER_VIEW_MESSAGE = 1024
FORMAT_VERSION = "1"
#: The keys of the ``topics`` metadata (``aslam.data_formats.recording.RecordingTopics``' fields).
TOPIC_KEYS = ("image", "odometry", "ground_truth", "camera_info")
CHUNK_SIZE_BYTES = 256 * 1024

# --- schemas ---------------------------------------------------------------------------------------

_NUMBER = {"type": "number"}
_INTEGER = {"type": "integer"}
_ACTION = {
    "type": "object",
    "description": "Relative SE(2) motion from the previous keyframe, from odometry (REP 103).",
    "properties": {"x_m": _NUMBER, "y_m": _NUMBER, "yaw_rad": _NUMBER},
    "required": ["x_m", "y_m", "yaw_rad"],
}
_HYPOTHESIS = {
    "type": "object",
    "properties": {
        "id": {**_INTEGER, "description": "Tree node id (unique over the run)."},
        "parent": {"type": ["integer", "null"], "description": "Tree node id of the parent."},
        "state": {**_INTEGER, "description": "State assigned to this keyframe (first-visit keyframe)."},
        "belief": {**_NUMBER, "description": "Normalised belief; beliefs of one keyframe sum to 1."},
        "new_state": {"type": "boolean", "description": "True when the hypothesis says 'a new place'."},
    },
    "required": ["id", "parent", "state", "belief", "new_state"],
}
KEYFRAME_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": KEYFRAME_SCHEMA_NAME,
    "type": "object",
    "properties": {
        "index": {**_INTEGER, "description": "Keyframe index, from 0."},
        "stamp_ns": {**_INTEGER, "description": "Stamp of the keyframe's image, ns."},
        "action": _ACTION,
        "hypotheses": {"type": "array", "items": _HYPOTHESIS, "description": "Best first."},
    },
    "required": ["index", "stamp_ns", "action", "hypotheses"],
}
GRAPH_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": GRAPH_SCHEMA_NAME,
    "type": "object",
    "properties": {
        "keyframes": {**_INTEGER, "description": "Keyframes in the map: the prior map's, then this run's."},
        "first_keyframe": {
            **_INTEGER,
            "description": "Index of this run's first keyframe (0, or the prior map's keyframes with --map).",
        },
        "states": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "id": _INTEGER,
                    "keyframes": {"type": "array", "items": _INTEGER},
                },
                "required": ["id", "keyframes"],
            },
        },
        "links": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "from": _INTEGER,
                    "to": _INTEGER,
                    "action": _ACTION,
                    "covariance": {
                        "type": "array",
                        "description": "3×3 row-major covariance of (x_m, y_m, yaw_rad).",
                        "items": {"type": "array", "items": _NUMBER},
                    },
                    "count": {**_INTEGER, "description": "Traversals of this link."},
                },
                "required": ["from", "to", "action", "covariance", "count"],
            },
        },
        "hypotheses": {"type": "array", "items": _HYPOTHESIS},
        "tree": {"type": "object", "description": "Hypothesis-tree statistics."},
    },
    "required": ["keyframes", "first_keyframe", "states", "links", "hypotheses", "tree"],
}
PLACE_VIEWS_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": PLACE_VIEWS_SCHEMA_NAME,
    "description": "The view stored with each place of the final map, for a later run to start in (--map).",
    "type": "object",
    "properties": {
        "observation_model": {"type": "string", "description": "The model that described the views."},
        "length": {**_INTEGER, "description": "Numbers per view."},
        "states": {"type": "array", "items": _INTEGER, "description": "Place ids, ascending."},
        "views": {
            "type": "string",
            "description": "The views, row per state: little-endian float32, base64.",
        },
    },
    "required": ["observation_model", "length", "states", "views"],
}


# --- reading: the writer's schemas with bounds ------------------------------------------------------

_SHA256 = re.compile(r"[0-9a-f]{64}")
"""A recording's or a map's identity as the metadata holds it: SHA-256, lowercase hex."""

#: Any number in an estimate file (actions, covariances, tree statistics) lies within this; the
#: recording reader refuses poses beyond 1e7 m, so larger values are damage, not data.
MAX_ABS_NUMBER = 1e15
MAX_ABS_COVARIANCE = 1e40
"""A covariance grows with the square of a step's length squared (the lateral drift term): a
carry or an odometry jump of 10⁷ m, which odometry may report, gives entries near 10²⁹."""
MAX_INTEGER = 2**63 - 1
_COVARIANCE_ROW = {"type": "array", "minItems": 3, "maxItems": 3}


def _bounded(schema: Any) -> Any:
    """A copy of ``schema`` whose numbers are finite and bounded, integers non-negative int64, and
    covariances 3×3; the reading schema of every message (``docs/formats.md``)."""
    if isinstance(schema, list):
        return [_bounded(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    out = {key: _bounded(value) for key, value in schema.items()}
    kind = out.get("type")
    if kind == "number":
        out.update(minimum=-MAX_ABS_NUMBER, maximum=MAX_ABS_NUMBER)
    elif kind == "integer" or kind == ["integer", "null"]:
        out.update(minimum=0, maximum=MAX_INTEGER)
    if out.get("description", "").startswith("3×3"):
        entry = {"type": "number", "minimum": -MAX_ABS_COVARIANCE, "maximum": MAX_ABS_COVARIANCE}
        out.update(minItems=3, maxItems=3, items={**out["items"], **_COVARIANCE_ROW, "items": entry})
    return out


def _reading_schemas() -> tuple[dict[str, Any], dict[str, Any]]:
    keyframe = _bounded(KEYFRAME_SCHEMA)
    graph = _bounded(GRAPH_SCHEMA)
    belief = {"type": "number", "minimum": 0.0, "maximum": 1.0}
    for hypotheses in (keyframe["properties"]["hypotheses"], graph["properties"]["hypotheses"]):
        hypotheses["items"]["properties"]["belief"] = belief
    number = {"type": "number", "minimum": -MAX_ABS_NUMBER, "maximum": MAX_ABS_NUMBER}
    graph["required"] = [key for key in graph["required"] if key != "first_keyframe"]  # older files: 0
    graph["properties"]["tree"].update(
        required=list(TreeStats.__dataclass_fields__),
        properties={name: number for name in TreeStats.__dataclass_fields__},
        additionalProperties=False,
    )
    return keyframe, graph


KEYFRAME_READING_SCHEMA, GRAPH_READING_SCHEMA = _reading_schemas()
PLACE_VIEWS_READING_SCHEMA = _bounded(PLACE_VIEWS_SCHEMA)
_validators: dict[str, Any] = {}


def _validate(document: Any, schema: dict[str, Any], what: str, path: Path) -> None:
    """EstimateError naming where ``document`` breaks ``schema``.

    fastjsonschema compiles the schema to Python once: 0.2 ms per keyframe message with 50
    hypotheses, where ``jsonschema``'s validator takes 6.4 ms (30 times the JSON parsing itself).
    """
    validate = _validators.get(what)
    if validate is None:
        import fastjsonschema

        validate = _validators[what] = fastjsonschema.compile(schema)
    try:
        validate(document)
    except Exception as err:  # fastjsonschema.JsonSchemaValueException, one line
        message = str(getattr(err, "message", err)).removeprefix("data.").removeprefix("data ")
        message = message if len(message) <= 160 else message[:157] + "..."
        raise EstimateError(f"invalid {what} message: {message}", path=path) from err


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number this format allows")


# --- records -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordingIdentity:
    """Which recording an estimate was made from."""

    path: str
    """Absolute path at estimate time."""
    size_bytes: int
    sha256: str
    """SHA-256 of the whole file, hex."""


@dataclass(frozen=True)
class MapIdentity:
    """The prior map a run started in (``estimate --map``): an earlier estimate file."""

    path: str
    """Absolute path at estimate time."""
    sha256: str
    keyframes: int
    """Keyframes in that map: this run's keyframes are numbered from here."""
    graph_sha256: str | None = None
    """:func:`map_digest` of that map: the same after it is estimated again with other timing or
    topics (other bytes), another for another run's map of the same layout. None in files written
    before it was stored (2026-12-05)."""


@dataclass(frozen=True)
class EstimateMetadata:
    tool_version: str
    config: dict[str, Any]
    recording: RecordingIdentity
    topics: dict[str, str | None]
    """image, odometry, ground_truth → the topic read (None: found in a bag)."""
    prior_map: MapIdentity | None = None

    def as_record(self) -> dict[str, str]:
        """The MCAP metadata map (strings only; structured values as JSON)."""
        record = {
            "format_version": FORMAT_VERSION,
            "tool_version": self.tool_version,
            "config": _dumps(self.config),
            "recording_path": files.utf8_file_name(self.recording.path),
            "recording_size_bytes": str(self.recording.size_bytes),
            "recording_sha256": self.recording.sha256,
            "topics": _dumps(self.topics),
        }
        if self.prior_map is not None:
            record["map_path"] = files.utf8_file_name(self.prior_map.path)
            record["map_sha256"] = self.prior_map.sha256
            record["map_keyframes"] = str(self.prior_map.keyframes)
            if self.prior_map.graph_sha256 is not None:
                record["map_graph_sha256"] = self.prior_map.graph_sha256
        return record

    @classmethod
    def from_record(cls, record: Mapping[str, str], path: Path) -> EstimateMetadata:
        version = record.get("format_version", FORMAT_VERSION)  # files before it had one: format 1
        if version != FORMAT_VERSION:
            raise EstimateError(
                f"estimate file format {version!r}, written by aslam {record.get('tool_version', '?')};"
                f" this aslam reads format {FORMAT_VERSION!r}",
                path=path,
            )
        try:
            metadata = cls(
                tool_version=record["tool_version"],
                config=json.loads(record["config"], parse_constant=_no_constant),
                recording=RecordingIdentity(
                    record["recording_path"],
                    int(record["recording_size_bytes"]),
                    record["recording_sha256"],
                ),
                topics=json.loads(record["topics"], parse_constant=_no_constant),
                prior_map=None
                if "map_path" not in record
                else MapIdentity(
                    record["map_path"],
                    record["map_sha256"],
                    int(record["map_keyframes"]),
                    record.get("map_graph_sha256"),
                ),
            )
        except (KeyError, ValueError, TypeError, RecursionError) as err:
            raise EstimateError(f"unreadable '{ESTIMATE_METADATA}' metadata ({err!r})", path=path) from err
        problem = metadata._problem()
        if problem is not None:
            raise EstimateError(f"invalid '{ESTIMATE_METADATA}' metadata: {problem}", path=path)
        return metadata

    def _problem(self) -> str | None:
        """What the writer never writes: a config that is not an object, topics that are not names."""
        if not isinstance(self.config, dict):
            return "config is not a JSON object"
        if not isinstance(self.topics, dict) or not all(
            key in TOPIC_KEYS and (value is None or isinstance(value, str))
            for key, value in self.topics.items()
        ):
            return f"topics must map {', '.join(TOPIC_KEYS)} to topic names (null: found in a bag)"
        if self.recording.size_bytes < 0:
            return "recording_size_bytes is negative"
        if not self.recording.path:  # ``report`` read the current folder as the recording
            return "recording_path is empty"
        digests: list[tuple[str, str | None]] = [("recording_sha256", self.recording.sha256)]
        if self.prior_map is not None:
            if self.prior_map.keyframes < 0:
                return "map_keyframes is negative"
            if not self.prior_map.path:
                return "map_path is empty"
            digests += [
                ("map_sha256", self.prior_map.sha256),
                ("map_graph_sha256", self.prior_map.graph_sha256),
            ]
        for name, digest in digests:
            if digest is not None and not _SHA256.fullmatch(digest):
                return f"{name} is not a SHA-256 digest (64 hex digits)"
        return None


@dataclass(frozen=True)
class Timing:
    """Wall-clock figures of one run (not deterministic, so kept apart)."""

    wall_s: float
    """Whole run: reading, decoding, histograms, SLAM, writing."""
    slam_s: float
    """Time inside the estimator's keyframe step only."""
    keyframes_per_second: float
    samples: int
    keyframes: int

    def as_record(self) -> dict[str, str]:
        return {k: repr(v) for k, v in asdict(self).items()}

    @classmethod
    def from_record(cls, record: Mapping[str, str], path: Path) -> Timing:
        try:
            return cls(
                wall_s=float(record["wall_s"]),
                slam_s=float(record["slam_s"]),
                keyframes_per_second=float(record["keyframes_per_second"]),
                samples=int(record["samples"]),
                keyframes=int(record["keyframes"]),
            )
        except (KeyError, ValueError) as err:
            raise EstimateError(f"unreadable '{TIMING_METADATA}' metadata ({err!r})", path=path) from err


class EstimateKeyframe(NamedTuple):
    index: int  # type: ignore[assignment]  # shadows tuple.index(), which nothing calls
    stamp_ns: int
    action: tuple[float, float, float]
    """(x_m, y_m, yaw_rad) since the previous keyframe."""
    hypotheses: tuple[Hypothesis, ...]
    """Best first."""


@dataclass(frozen=True)
class EstimateGraph:
    """The ``/aslam/graph`` message: the best hypothesis's map and the final hypotheses."""

    keyframes: int
    """Keyframes in the map: the prior map's (``first_keyframe`` of them), then this run's."""
    states: tuple[MapState, ...]
    links: tuple[MapLink, ...]
    hypotheses: tuple[Hypothesis, ...]
    tree: TreeStats
    first_keyframe: int = 0


@dataclass(frozen=True)
class PlaceViews:
    """The view stored with each place of the final map (what ``estimate --map`` starts from)."""

    observation_model: str
    states: np.ndarray
    """(P,) int64 place ids, ascending."""
    views: np.ndarray
    """(P, length) float32, row per place."""

    def messages(self) -> Iterator[dict[str, Any]]:
        """``/aslam/place_views`` messages, ``PLACES_PER_VIEW_MESSAGE`` places each."""
        for start in range(0, len(self.states), PLACES_PER_VIEW_MESSAGE):
            rows = slice(start, start + PLACES_PER_VIEW_MESSAGE)
            data = np.ascontiguousarray(self.views[rows], dtype="<f4").tobytes()
            yield {
                "observation_model": self.observation_model,
                "length": int(self.views.shape[1]),
                "states": [int(state) for state in self.states[rows]],
                "views": base64.b64encode(data).decode("ascii"),
            }


@dataclass(frozen=True)
class EstimateFile:
    metadata: EstimateMetadata
    timing: Timing | None
    graph: EstimateGraph


# --- JSON helpers ------------------------------------------------------------------------------


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"), allow_nan=False)


def hypothesis_json(h: Hypothesis) -> dict[str, Any]:
    return {
        "id": h.id,
        "parent": h.parent_id,
        "state": h.state,
        "belief": h.belief,
        "new_state": h.is_new_state,
    }


def action_json(action: tuple[float, float, float] | Any) -> dict[str, float]:
    x, y, yaw = (float(v) for v in action)
    return {"x_m": x, "y_m": y, "yaw_rad": yaw}


def keyframe_message(step: StepResult) -> dict[str, Any]:
    return {
        "index": step.keyframe,
        "stamp_ns": step.stamp_ns,
        "action": action_json(step.action),
        "hypotheses": [hypothesis_json(h) for h in step.hypotheses],
    }


def graph_message(result: EstimateResult) -> dict[str, Any]:
    return {
        "keyframes": result.first_keyframe + len(result.keyframe_stamps_ns),
        "first_keyframe": result.first_keyframe,
        "states": [{"id": s.id, "keyframes": list(s.keyframes)} for s in result.states],
        "links": [
            {
                "from": link.from_state,
                "to": link.to_state,
                "action": action_json(link.action),
                "covariance": [[float(v) for v in row] for row in link.covariance],
                "count": link.count,
            }
            for link in result.links
        ],
        "hypotheses": [hypothesis_json(h) for h in result.hypotheses],
        "tree": asdict(result.stats),
    }


# --- writing -------------------------------------------------------------------------------------


class EstimateWriter:
    """Writes an estimate file; use as a context manager.

    Written under a hidden temporary name and renamed to ``path`` by :meth:`finish`. Leaving the
    ``with`` block without finishing (an exception, KeyboardInterrupt) removes the temporary file,
    so nothing ever appears under ``path`` half-written. The same calls give the same bytes.
    """

    def __init__(self, path: Path, *, tool_version: str, force: bool = False) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._output = files.AtomicFile(self.path, force=force, error=EstimateError)
        self.partial_path = self._output.partial_path
        self._file = self._output.file
        try:
            self._writer = Writer(self._file, chunk_size=CHUNK_SIZE_BYTES, compression=CompressionType.ZSTD)
            self._writer.start(profile="", library=f"aslam {tool_version}")
            keyframe_schema = self._writer.register_schema(
                KEYFRAME_SCHEMA_NAME, "jsonschema", _dumps(KEYFRAME_SCHEMA).encode()
            )
            graph_schema = self._writer.register_schema(
                GRAPH_SCHEMA_NAME, "jsonschema", _dumps(GRAPH_SCHEMA).encode()
            )
            self._keyframe_channel = self._writer.register_channel(KEYFRAME_TOPIC, "json", keyframe_schema)
            self._graph_channel = self._writer.register_channel(GRAPH_TOPIC, "json", graph_schema)
            views_schema = self._writer.register_schema(
                PLACE_VIEWS_SCHEMA_NAME, "jsonschema", _dumps(PLACE_VIEWS_SCHEMA).encode()
            )
            self._views_channel = self._writer.register_channel(PLACE_VIEWS_TOPIC, "json", views_schema)
        except BaseException:
            self.abort()
            raise
        self._sequence = 0
        self._last_stamp_ns = 0

    def __enter__(self) -> EstimateWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if not self._output.closed:
            self.abort()

    def _add(self, channel: int, stamp_ns: int, message: dict[str, Any]) -> None:
        try:
            self._writer.add_message(
                channel,
                log_time=stamp_ns,
                publish_time=stamp_ns,
                data=_dumps(message).encode(),
                sequence=self._sequence,
            )
        except OSError as err:
            raise EstimateError(f"cannot write: {err.strerror or err}", path=self.path) from err
        self._sequence += 1

    def write_keyframe(self, step: StepResult) -> None:
        self._last_stamp_ns = step.stamp_ns
        self._add(self._keyframe_channel, step.stamp_ns, keyframe_message(step))

    def finish(
        self,
        result: EstimateResult,
        metadata: EstimateMetadata,
        timing: Timing | None,
        scene: MetricScene | None = None,
        views: PlaceViews | None = None,
    ) -> None:
        """Write the graph, the places' views (if given), the metric view for Foxglove (if given)
        and the metadata, close, and move the file to its final name."""

        def last_writes() -> None:
            self._add(self._graph_channel, self._last_stamp_ns, graph_message(result))
            if views is not None:
                for message in views.messages():
                    self._add(self._views_channel, self._last_stamp_ns, message)
            if scene is not None:
                from aslam.data_formats.foxglove import write_scene

                write_scene(self._writer, scene)
            self._writer.add_metadata(ESTIMATE_METADATA, files.utf8_metadata(metadata.as_record()))
            if timing is not None:
                self._writer.add_metadata(TIMING_METADATA, timing.as_record())
            self._writer.finish()

        self._output.commit(finish=last_writes)

    def abort(self) -> None:
        """Drop the partial file; nothing is left under the final name."""
        self._output.abort()


# --- reading -------------------------------------------------------------------------------------


EstimateSource = Path | McapFile
"""An estimate file by its path, or opened by :func:`open_estimate`."""


def open_estimate(path: Path) -> McapFile:
    """The estimate file, opened and checked: a complete MCAP file with the estimate metadata."""
    source = McapFile(Path(path), error=EstimateError, what="an estimate file", require_complete=True)
    if source.metadata(ESTIMATE_METADATA) is None:
        raise EstimateError(
            f"not an aslam estimate file (no '{ESTIMATE_METADATA}' metadata; is it a recording?)",
            path=source.path,
        )
    return source


def _open(estimate: EstimateSource) -> McapFile:
    return estimate if isinstance(estimate, McapFile) else open_estimate(estimate)


def _messages(source: McapFile, topic: str) -> Generator[dict[str, Any], None, None]:
    for _schema, _channel, message in source.messages([topic]):
        try:
            decoded = json.loads(message.data, parse_constant=_no_constant)
        except (ValueError, RecursionError) as err:
            raise EstimateError(f"corrupt JSON on '{topic}' ({err})", path=source.path) from err
        yield decoded


def _hypothesis(raw: Mapping[str, Any]) -> Hypothesis:
    return Hypothesis(
        int(raw["id"]),
        None if raw["parent"] is None else int(raw["parent"]),
        int(raw["state"]),
        float(raw["belief"]),
        bool(raw["new_state"]),
    )


def _action(raw: Mapping[str, Any]) -> tuple[float, float, float]:
    return (float(raw["x_m"]), float(raw["y_m"]), float(raw["yaw_rad"]))


def iter_keyframes(estimate: EstimateSource) -> Generator[EstimateKeyframe, None, None]:
    """The keyframes of an estimate file in order, streamed (one chunk in memory at a time)."""
    return _iter_keyframes(_open(estimate))  # fails early, naming the file, on anything but an estimate


def _iter_keyframes(source: McapFile) -> Generator[EstimateKeyframe, None, None]:
    for raw in _messages(source, KEYFRAME_TOPIC):
        _validate(raw, KEYFRAME_READING_SCHEMA, "keyframe", source.path)
        try:
            yield EstimateKeyframe(
                int(raw["index"]),
                int(raw["stamp_ns"]),
                _action(raw["action"]),
                tuple(_hypothesis(h) for h in raw["hypotheses"]),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise EstimateError(f"malformed keyframe message ({err!r})", path=source.path) from err


def _graph(raw: Mapping[str, Any], path: Path) -> EstimateGraph:
    _validate(raw, GRAPH_READING_SCHEMA, "graph", path)
    try:
        graph = EstimateGraph(
            keyframes=int(raw["keyframes"]),
            states=tuple(
                MapState(int(s["id"]), tuple(int(k) for k in s["keyframes"])) for s in raw["states"]
            ),
            links=tuple(
                MapLink(
                    int(link["from"]),
                    int(link["to"]),
                    _action(link["action"]),
                    tuple(tuple(float(v) for v in row) for row in link["covariance"]),  # type: ignore[misc]
                    int(link["count"]),
                )
                for link in raw["links"]
            ),
            hypotheses=tuple(_hypothesis(h) for h in raw["hypotheses"]),
            tree=TreeStats(**raw["tree"]),
            first_keyframe=int(raw.get("first_keyframe", 0)),
        )
    except (KeyError, TypeError, ValueError) as err:
        raise EstimateError(f"malformed '{GRAPH_TOPIC}' message ({err!r})", path=path) from err
    problem = _graph_reference_problem(graph)
    if problem is not None:
        raise EstimateError(f"inconsistent '{GRAPH_TOPIC}' message: {problem}", path=path)
    return graph


def _graph_reference_problem(graph: EstimateGraph) -> str | None:
    """What a schema cannot say: links name states that exist; every keyframe is in exactly one
    state (so the count is the file's, never a number a map in ``--map`` allocates by: 10¹⁵ asked
    for petabytes); each link's covariance is one (symmetric, positive definite: a zero one
    divided by zero in the motion model)."""
    ids = {state.id for state in graph.states}
    if graph.first_keyframe > graph.keyframes:
        return f"first_keyframe {graph.first_keyframe} is beyond the {graph.keyframes} keyframes"
    if len(ids) != len(graph.states):
        return "two states share an id"
    seen = 0
    for state in graph.states:
        if any(k >= graph.keyframes for k in state.keyframes):
            return f"state {state.id} names a keyframe beyond the {graph.keyframes} keyframes"
        seen += len(state.keyframes)
    if seen != graph.keyframes or len({k for state in graph.states for k in state.keyframes}) != seen:
        return f"the states do not hold each of the {graph.keyframes} keyframes once"
    for link in graph.links:
        if link.from_state not in ids or link.to_state not in ids:
            return f"link {link.from_state} → {link.to_state} names a state that does not exist"
    if graph.links:
        covariances = np.array([link.covariance for link in graph.links], dtype=float)
        symmetric = np.abs(covariances - covariances.transpose(0, 2, 1)) <= 1e-9 * np.abs(covariances).max(
            initial=0.0
        )
        with np.errstate(all="ignore"):
            definite = np.linalg.eigvalsh(covariances).min(axis=1) > 0
        bad = np.flatnonzero(~(symmetric.all(axis=(1, 2)) & definite))
        if len(bad):
            link = graph.links[int(bad[0])]
            return (
                f"link {link.from_state} → {link.to_state}: its covariance is not symmetric positive definite"
            )
    return None


def map_digest(graph: EstimateGraph) -> str:
    """SHA-256 of a map as a run in it depends on it: its keyframes, each place's keyframes, each
    link's measurement and count. Timing and topics, which change an estimate file's bytes but not
    its map, are left out; another run's odometry changes every link."""
    document = [
        graph.keyframes,
        [[state.id, list(state.keyframes)] for state in graph.states],
        [
            [
                link.from_state,
                link.to_state,
                list(link.action),
                [list(row) for row in link.covariance],
                link.count,
            ]
            for link in graph.links
        ],
    ]
    return hashlib.sha256(json.dumps(document, separators=(",", ":")).encode()).hexdigest()


def read_estimate(estimate: EstimateSource) -> EstimateFile:
    """The metadata, the timing (None if omitted) and the final graph of an estimate file."""
    source = _open(estimate)
    metadata = EstimateMetadata.from_record(source.metadata(ESTIMATE_METADATA) or {}, source.path)
    timing_record = source.metadata(TIMING_METADATA)
    timing = None if timing_record is None else Timing.from_record(timing_record, source.path)
    with closing(_messages(source, GRAPH_TOPIC)) as graphs:
        graph = next(graphs, None)
    if graph is None:
        raise EstimateError(f"no '{GRAPH_TOPIC}' message (the estimate is incomplete)", path=source.path)
    return EstimateFile(metadata, timing, _graph(graph, source.path))


def read_place_views(estimate: EstimateSource) -> PlaceViews:
    """The stored views of an estimate's places, checked against its graph's places."""
    source = _open(estimate)
    states: list[int] = []
    blocks: list[np.ndarray] = []
    model = None
    with closing(_messages(source, PLACE_VIEWS_TOPIC)) as messages:
        for raw in messages:
            _validate(raw, PLACE_VIEWS_READING_SCHEMA, "place views", source.path)
            length = int(raw["length"])
            try:
                data = base64.b64decode(raw["views"], validate=True)
            except (binascii.Error, ValueError) as err:
                raise EstimateError(f"corrupt place views ({err})", path=source.path) from err
            if length == 0 or len(data) != 4 * length * len(raw["states"]):
                raise EstimateError("place views of the wrong size", path=source.path)
            if model is not None and (raw["observation_model"], length) != (model, blocks[-1].shape[1]):
                raise EstimateError("place views of two kinds", path=source.path)
            model = raw["observation_model"]
            states.extend(int(state) for state in raw["states"])
            blocks.append(np.frombuffer(data, dtype="<f4").reshape(-1, length).astype(np.float32))
    if model is None:
        raise EstimateError(
            f"no '{PLACE_VIEWS_TOPIC}' messages: the map's views were not stored (estimate it again)",
            path=source.path,
        )
    views = np.concatenate(blocks)
    if not np.isfinite(views).all():
        raise EstimateError("place views hold a non-finite number", path=source.path)
    return PlaceViews(model, np.array(states, dtype=np.int64), views)
