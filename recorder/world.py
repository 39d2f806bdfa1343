"""Worlds the route drives through: generated around the route, or loaded from a scene file.

**Generated worlds** (:func:`generate_world`) are built from the commanded path and the seed:

1. the path is rasterised onto a grid of ``cell_m`` cells (0.25 m); cells within
   ``corridor_half_width_m`` (1 m) of the path are free, so corridors are about 2 m wide and
   junctions appear wherever the path crosses itself;
2. seeded alcoves and small rooms are opened off the corridors;
3. walls are the boundaries between free and solid cells, merged into straight runs and cut into
   panels of 1.5–3 m, each with its own procedural texture (wallpaper, brick, wood, tiles, panelling),
   baseboard, and sometimes a door (with a 3-D frame) or a poster or painting;
4. floor (a few zones with different floor textures) and ceiling cover the free cells; ceiling light
   panels are placed every few metres along the path.

``aliasing`` (0…1) is the fraction of wall panels whose texture is drawn from a small shared set
(:data:`N_SHARED_TEXTURES` plain wallpapers: no door, poster or painting) and the fraction of floor
zones that take the one shared floor texture, so that distinct places look alike.  At 1 every
surface comes from the shared set (no doors, no pictures, one floor): places differ only by the
layout — corridors, junctions, alcoves, lights.  The aliasing draws use their own random stream,
so changing the value does not change the rest of the world.

A kidnap (``connected[i]`` False) is not a path: no corridor is carved along it.

**Scene files** (:func:`load_scene_world`): any ``.glb``, ``.gltf`` or ``.obj`` trimesh can load,
in metres with +z up and the floor at z = 0 (the frame of the route).  Before anything is rendered
the route is checked against the mesh: every segment of the path at camera height must not cross
the mesh and every pose must have floor below.  The files it loads besides itself (buffers,
materials, textures) are noted as it loads them (:func:`scene_companions`).
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from aslam.recorder import textures as tex
from aslam.recorder.config import GENERATED_CEILING_M
from aslam.recorder.errors import WorldError

if TYPE_CHECKING:
    import trimesh

CELL_M = 0.25
CORRIDOR_HALF_WIDTH_M = 1.0
HEIGHT_M = GENERATED_CEILING_M
PANEL_CELLS = (6, 12)  # panel length in cells: 1.5–3 m
N_SHARED_TEXTURES = 3
DOOR_WIDTH_M = 0.9
DOOR_HEIGHT_M = 2.05
BASEBOARD_M = 0.1
LIGHT_SPACING_M = 3.0
LIGHT_SIZE_M = 0.6
FLOOR_ZONE_M = 4.0
N_FLOOR_TEXTURES = 3


@dataclass(frozen=True)
class Panel:
    """One textured wall quad from ``p0`` to ``p1`` (seen from the free side, ``p0`` is on the left).

    ``texture`` indexes :attr:`GridWorld.wall_textures`; ``u1`` is the fraction of that texture's
    width the panel uses (shared textures are wider than most panels).
    """

    p0: tuple[float, float]
    p1: tuple[float, float]
    normal: tuple[float, float]
    texture: int
    u1: float = 1.0

    @property
    def length_m(self) -> float:
        return math.hypot(self.p1[0] - self.p0[0], self.p1[1] - self.p0[1])


@dataclass
class GridWorld:
    """A generated world: occupancy grid, wall panels with their textures, floor, ceiling, lights."""

    origin_xy: tuple[float, float]
    cell_m: float
    free: np.ndarray  # (ny, nx) bool, row j covers y in origin_y + [j, j+1) * cell_m
    height_m: float
    panels: list[Panel]
    wall_textures: list[np.ndarray]
    floor_zone: np.ndarray  # (ny, nx) int: index into floor_textures
    floor_textures: list[np.ndarray]
    ceiling_texture: np.ndarray
    lights_xy: np.ndarray  # (n, 2) ceiling light panel centres
    door_frames: list[tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = field(
        default_factory=list
    )  # (left end, right end, normal) of each door opening
    n_alcoves: int = 0
    aliasing: float = 0.0
    n_shared_panels: int = 0

    kind = "generated"

    def cell_of(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        i = np.floor((np.asarray(x) - self.origin_xy[0]) / self.cell_m).astype(int)
        j = np.floor((np.asarray(y) - self.origin_xy[1]) / self.cell_m).astype(int)
        return i, j

    def is_free(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Whether points are in free space (outside the grid is solid)."""
        i, j = self.cell_of(x, y)
        ny, nx = self.free.shape
        inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
        out = np.zeros(np.shape(i), dtype=bool)
        out[inside] = self.free[j[inside], i[inside]]
        return out

    def describe(self) -> str:
        doc = {
            "kind": self.kind,
            "cell_m": self.cell_m,
            "corridor_width_m": 2 * CORRIDOR_HALF_WIDTH_M,
            "height_m": self.height_m,
            "free_area_m2": round(float(self.free.sum()) * self.cell_m**2, 3),
            "wall_panels": len(self.panels),
            "doors": len(self.door_frames),
            "alcoves": self.n_alcoves,
            "lights": len(self.lights_xy),
            "aliasing": self.aliasing,
            "shared_textures": N_SHARED_TEXTURES,
            "aliased_panels": self.n_shared_panels,
        }
        return json.dumps(doc, separators=(",", ":"))


# ------------------------------------------------------------------------------------ generation


def _segment_distance(px: np.ndarray, py: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    length2 = float(d @ d)
    if length2 == 0.0:
        return np.hypot(px - a[0], py - a[1])
    t = np.clip(((px - a[0]) * d[0] + (py - a[1]) * d[1]) / length2, 0.0, 1.0)
    return np.hypot(px - (a[0] + t * d[0]), py - (a[1] + t * d[1]))


def _unique_segments(
    points: np.ndarray, connected: np.ndarray | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Path segments with repeats (later laps, reverse drives) and kidnaps removed."""
    seen: set[tuple] = set()
    out = []
    for i, (a, b) in enumerate(itertools.pairwise(points)):
        if connected is not None and not connected[i]:
            continue
        key = tuple(np.round(np.concatenate([a, b]), 6))
        rkey = tuple(np.round(np.concatenate([b, a]), 6))
        if key in seen or rkey in seen:
            continue
        seen.add(key)
        out.append((a, b))
    return out


def _carve_alcoves(free: np.ndarray, centres_x, centres_y, segments, rng, cell: float) -> int:
    """Open seeded alcoves and small rooms off the corridors; returns how many were opened."""
    moving = [(a, b) for a, b in segments if np.hypot(*(b - a)) > 1e-9]
    total = sum(float(np.hypot(*(b - a))) for a, b in moving)
    n = int(rng.poisson(total / 6.0)) if moving else 0
    opened = 0
    for _ in range(n):
        a, b = moving[int(rng.integers(len(moving)))]
        d = (b - a) / np.hypot(*(b - a))
        normal = np.array([-d[1], d[0]]) * (1 if rng.random() < 0.5 else -1)
        along = a + (b - a) * rng.random()
        depth = rng.uniform(1.0, 3.0)
        width = rng.uniform(1.5, 3.5)
        near = along + normal * (CORRIDOR_HALF_WIDTH_M - 0.01)
        lo = near - d * width / 2
        corners = np.array([lo, lo + d * width, lo + normal * depth, lo + d * width + normal * depth])
        xmin, ymin = corners.min(axis=0)
        xmax, ymax = corners.max(axis=0)
        mask = (centres_x >= xmin) & (centres_x <= xmax) & (centres_y >= ymin) & (centres_y <= ymax)
        free |= mask
        opened += 1
    return opened


def _runs(boundary: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Maximal runs of equal non-zero values along each row: (row, start, stop, value)."""
    out = []
    for r, row in enumerate(boundary):
        c = 0
        n = len(row)
        while c < n:
            v = row[c]
            if v == 0:
                c += 1
                continue
            s = c
            while c < n and row[c] == v:
                c += 1
            out.append((r, s, c, int(v)))
    return out


def _cut(length: int, rng: np.random.Generator) -> list[int]:
    """Cut a run of ``length`` cells into panels of PANEL_CELLS[0]..PANEL_CELLS[1] cells."""
    lo, hi = PANEL_CELLS
    pieces = []
    while length > hi:
        k = int(rng.integers(lo, min(hi, length - lo) + 1))
        pieces.append(k)
        length -= k
    pieces.append(length)
    return pieces


def _panel_texture(
    rng: np.random.Generator, length_m: float, height_m: float, *, decorated: bool = True
) -> tuple[np.ndarray, float | None]:
    """A wall panel's texture; returns it and the door's left edge in metres (None: no door).

    ``decorated=False`` gives the plain wallpaper (with its baseboard) and never a door or picture.
    """
    w = max(8, round(length_m * tex.PX_PER_M))
    h = round(height_m * tex.PX_PER_M)
    gen = tex.WALLPAPERS[int(rng.integers(len(tex.WALLPAPERS)))]
    img = gen(rng, h, w)
    base_h = round(BASEBOARD_M * tex.PX_PER_M)
    board = np.clip(np.array([235.0, 230, 220]) * rng.uniform(0.3, 1.0), 0, 255)
    img[h - base_h :] = board.astype(np.uint8)
    img[h - base_h] = (board * 0.6).astype(np.uint8)
    door_at = None
    if not decorated:
        return img, None
    roll = rng.random()
    if length_m >= 1.4 and roll < 0.22:
        dw, dh = round(DOOR_WIDTH_M * tex.PX_PER_M), round(DOOR_HEIGHT_M * tex.PX_PER_M)
        x0 = int(rng.integers(4, max(5, w - dw - 4)))
        img[h - dh :, x0 : x0 + dw] = tex.door(rng, dh, dw)
        door_at = x0 / tex.PX_PER_M
    elif roll < 0.65:
        ph = int(rng.uniform(0.45, 0.9) * tex.PX_PER_M)
        pw = int(min(w - 16, ph * rng.uniform(0.6, 1.5)))
        if pw > 16:
            pic = tex.poster(rng, ph, pw) if rng.random() < 0.5 else tex.painting(rng, ph, pw)
            pic = tex.framed(rng, pic)
            fh, fw = pic.shape[:2]
            cy = int(h - 1.55 * tex.PX_PER_M)
            x0 = int(rng.integers(4, max(5, w - fw - 4)))
            y0 = max(2, cy - fh // 2)
            # a soft drop shadow makes the frame read as an object on the wall
            img[y0 + 3 : y0 + fh + 3, x0 + 3 : x0 + fw + 3] = (
                img[y0 + 3 : y0 + fh + 3, x0 + 3 : x0 + fw + 3] * 0.6
            ).astype(np.uint8)
            img[y0 : y0 + fh, x0 : x0 + fw] = pic[: h - y0, : w - x0]
    return img, door_at


def generate_world(
    commanded: np.ndarray,
    seed: int,
    *,
    aliasing: float = 0.0,
    connected: np.ndarray | None = None,
    true_path: np.ndarray | None = None,
) -> GridWorld:
    """Build a world around the commanded path (see the module docstring), deterministic per seed.

    ``connected[i]`` is False where action ``i`` is a kidnap.  ``true_path`` (when the truth drifts
    off the route, ``--noise-model paper``) gets a corridor of its own too, so the camera stays in
    free space; alcoves and lights still follow the commanded path, so their density does not
    depend on the noise.
    """
    rng = np.random.default_rng([seed, 0])
    alias_rng = np.random.default_rng([seed, 2])
    points = np.asarray(commanded, dtype=float)[:, :2]
    extra = None if true_path is None else np.asarray(true_path, dtype=float)[:, :2]
    everything = points if extra is None else np.concatenate([points, extra])
    cell = CELL_M
    margin = CORRIDOR_HALF_WIDTH_M + 3.5 + 2 * cell
    lo = np.floor((everything.min(axis=0) - margin) / cell) * cell
    hi = np.ceil((everything.max(axis=0) + margin) / cell) * cell
    nx, ny = (np.round((hi - lo) / cell)).astype(int)
    cx = lo[0] + (np.arange(nx) + 0.5) * cell
    cy = lo[1] + (np.arange(ny) + 0.5) * cell
    centres_x, centres_y = np.meshgrid(cx, cy)
    segments = _unique_segments(points, connected)
    free = np.zeros((ny, nx), dtype=bool)
    corridors = segments or [(points[0], points[0])]
    if extra is not None:
        corridors = corridors + _unique_segments(extra, connected)
    for a, b in corridors:
        free |= _segment_distance(centres_x, centres_y, a, b) <= CORRIDOR_HALF_WIDTH_M
    n_alcoves = _carve_alcoves(free, centres_x, centres_y, segments, rng, cell)
    # keep a solid border so every free cell is enclosed
    free[:1] = free[-1:] = False
    free[:, :1] = free[:, -1:] = False

    shared = [
        _panel_texture(alias_rng, PANEL_CELLS[1] * cell, HEIGHT_M, decorated=False)[0]
        for _ in range(N_SHARED_TEXTURES)
    ]
    wall_textures: list[np.ndarray] = list(shared)
    panels: list[Panel] = []
    doors = []
    n_shared = 0

    f = free.astype(np.int8)
    # horizontal walls between rows j-1 and j: +1 = free above (wall faces +y), -1 = free below
    horiz = f[1:, :] - f[:-1, :]  # (ny-1, nx); boundary at y = lo_y + (r+1)*cell
    vert = f[:, 1:] - f[:, :-1]  # (ny, nx-1); boundary at x = lo_x + (c+1)*cell
    walls = []
    for r, s, e, v in _runs(horiz):
        y = lo[1] + (r + 1) * cell
        normal = (0.0, float(v))
        # seen from the free side, left-to-right runs along (-n_y, n_x)
        xs = (lo[0] + s * cell, lo[0] + e * cell)
        walls.append((xs if v < 0 else xs[::-1], (y, y), normal, e - s, "h"))
    for c, s, e, v in _runs(vert.T):
        x = lo[0] + (c + 1) * cell
        normal = (float(v), 0.0)
        ys = (lo[1] + s * cell, lo[1] + e * cell)
        walls.append(((x, x), ys if v > 0 else ys[::-1], normal, e - s, "v"))
    for (x0, x1), (y0, y1), normal, n_cells, _ in walls:
        direction = np.array([x1 - x0, y1 - y0]) / (n_cells * cell)
        start = np.array([x0, y0])
        offset = 0
        for k in range(len(pieces := _cut(n_cells, rng))):
            length = pieces[k] * cell
            p0 = start + direction * offset * cell
            p1 = p0 + direction * length
            offset += pieces[k]
            own, door_at = _panel_texture(rng, length, HEIGHT_M)
            if alias_rng.random() < aliasing:
                index = int(alias_rng.integers(N_SHARED_TEXTURES))
                panels.append(Panel(tuple(p0), tuple(p1), normal, index, length / (PANEL_CELLS[1] * cell)))
                n_shared += 1
                continue
            alias_rng.integers(N_SHARED_TEXTURES)  # keep the aliasing stream aligned across values
            wall_textures.append(own)
            panels.append(Panel(tuple(p0), tuple(p1), normal, len(wall_textures) - 1))
            if door_at is not None:
                a = p0 + direction * door_at
                doors.append((tuple(a), tuple(a + direction * DOOR_WIDTH_M), normal))

    zones_x = np.floor((centres_x - lo[0]) / FLOOR_ZONE_M).astype(int)
    zones_y = np.floor((centres_y - lo[1]) / FLOOR_ZONE_M).astype(int)
    zone_choice = rng.integers(N_FLOOR_TEXTURES, size=(zones_y.max() + 1, zones_x.max() + 1))
    # aliased zones take the shared floor texture (index 0)
    zone_choice = np.where(alias_rng.random(zone_choice.shape) < aliasing, 0, zone_choice)
    floor_zone = zone_choice[zones_y, zones_x]
    floor_textures = [tex.floor_texture(rng) for _ in range(N_FLOOR_TEXTURES)]
    ceiling = tex.ceiling_texture(rng)

    world = GridWorld(
        origin_xy=(float(lo[0]), float(lo[1])),
        cell_m=cell,
        free=free,
        height_m=HEIGHT_M,
        panels=panels,
        wall_textures=wall_textures,
        floor_zone=floor_zone,
        floor_textures=floor_textures,
        ceiling_texture=ceiling,
        lights_xy=np.zeros((0, 2)),
        door_frames=doors,
        n_alcoves=n_alcoves,
        aliasing=aliasing,
        n_shared_panels=n_shared,
    )
    world.lights_xy = _place_lights(world, segments)
    return world


def _place_lights(world: GridWorld, segments) -> np.ndarray:
    """Light panel centres every LIGHT_SPACING_M along the path, at least that far apart."""
    lights: list[np.ndarray] = []
    for a, b in segments:
        length = float(np.hypot(*(b - a)))
        steps = max(1, math.ceil(length / 0.5))
        for t in np.linspace(0.0, 1.0, steps + 1):
            p = a + (b - a) * t
            if all(np.hypot(*(p - q)) >= LIGHT_SPACING_M - 1e-9 for q in lights):
                lights.append(p)
    return np.array(lights).reshape(-1, 2)


# ------------------------------------------------------------------------------------ scene files


@dataclass
class SceneWorld:
    """A user scene loaded with trimesh (metres, +z up, floor at z = 0)."""

    path: Path
    scene: trimesh.Scene
    mesh: trimesh.Trimesh
    """The whole scene in world coordinates, for ray tests."""
    companions: dict[str, str | None]
    """The other files the scene file loads, name → SHA-256 (None: named but missing); see
    :class:`~aslam.recorder.scene_files.CompanionResolver`."""

    kind = "scene-file"

    def describe(self) -> str:
        lo, hi = np.asarray(self.mesh.bounds)
        doc = {
            "kind": self.kind,
            "file": self.path.name,
            "triangles": len(self.mesh.faces),
            "bounds_m": [np.round(lo, 3).tolist(), np.round(hi, 3).tolist()],
        }
        return json.dumps(doc, separators=(",", ":"))


SCENE_SUFFIXES = (".glb", ".gltf", ".obj")


def load_scene_world(path: Path) -> SceneWorld:
    """Load a scene file with trimesh; one-line :class:`WorldError` when it cannot be used."""
    import trimesh

    from aslam.recorder.scene_files import CompanionResolver

    path = Path(path)
    if path.is_dir():  # (an empty --world names the current folder)
        raise WorldError(f"is a directory, not a scene file ({', '.join(SCENE_SUFFIXES)})", path=path)
    if path.suffix.lower() not in SCENE_SUFFIXES:
        raise WorldError(
            f"unsupported scene type '{path.suffix}' (use {', '.join(SCENE_SUFFIXES)})", path=path
        )
    if not path.is_file():
        raise WorldError("scene file not found", path=path)
    resolver = CompanionResolver(str(path))
    try:
        scene: trimesh.Scene = trimesh.load(path, force="scene", resolver=resolver)  # type: ignore[assignment]  # a Scene, forced
    except Exception as err:  # trimesh raises many types for malformed files
        raise WorldError(f"cannot load scene: {type(err).__name__}: {err}", path=path) from err
    try:
        mesh = scene.to_geometry()
    except Exception as err:
        raise WorldError(f"cannot flatten scene geometry: {err}", path=path) from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise WorldError("scene has no triangle geometry", path=path)
    return SceneWorld(path, scene, mesh, resolver.read)


def scene_companions(path: Path) -> dict[str, str | None]:
    """The files besides ``path`` that loading it reads (glTF buffers and images, OBJ materials and
    their textures), name → SHA-256: with the file's own bytes, what decides the world.

    Empty for a scene that cannot be loaded: its render fails, saying why, and is never kept.
    """
    try:
        return load_scene_world(path).companions
    except WorldError:
        return {}


def ray_distance(triangles: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> float:
    """Distance along a unit ray to the nearest triangle it hits (Möller–Trumbore), ``inf`` if none.

    Plain numpy over all triangles (no rtree/embree dependency); both faces count as hits.
    """
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    t_vec = origin - v0
    u = np.einsum("ij,ij->i", t_vec, p) * inv
    q = np.cross(t_vec, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    return float(t[hit].min()) if hit.any() else math.inf


def _where(i: int, actions_json: list[dict]) -> str:
    if i == 0:
        return "the start pose"
    return f"action {i - 1} ({json.dumps(actions_json[i - 1])})"


#: What a true path that leaves free space is blamed on, in the error message.
TRUE_PATH = "the true path (--jitter-m, --wander-m, --noise-model)"
#: Clearance of the true path from walls: beyond the camera's near clip plane (0.05 m).
TRUE_PATH_CLEARANCE_M = 0.06
#: Clearance of the true path from the walls of a generated world (its corridors are 2 m wide).
GENERATED_CLEARANCE_M = 0.1


def check_route_in_scene(
    world: SceneWorld,
    commanded: np.ndarray,
    actions_json: list[dict],
    camera_height_m: float,
    *,
    clearance_m: float = 0.15,
    connected: np.ndarray | None = None,
    what: str = "route",
) -> None:
    """Refuse a route that leaves free space: raise :class:`WorldError` naming the first bad action.

    Each driven segment at camera height is ray-tested against the mesh (plus ``clearance_m`` so
    the jittered true pose and the near clip plane stay clear), and every pose needs floor below.
    A pose not driven to (the start, a kidnap's landing: ``connected[i - 1]`` False) is ray-tested
    in eight directions around it instead: one set down inside a wall would render the wall's inside.
    ``what`` names the path in the message (the commanded route, or the true path with :data:`TRUE_PATH`).
    """
    triangles = np.asarray(world.mesh.triangles, dtype=float)
    points = np.asarray(commanded, dtype=float)
    origins = np.column_stack([points[:, :2], np.full(len(points), camera_height_m)])
    checked: set[tuple] = set()

    down = np.array([0.0, 0.0, -1.0])
    for i in range(len(points)):
        key = tuple(np.round(origins[max(0, i - 1)], 6)) + tuple(np.round(origins[i], 6))
        if key in checked:  # later laps repeat the same segments
            continue
        checked.add(key)
        driven = i > 0 and (connected is None or bool(connected[i - 1]))
        d = origins[i] - origins[i - 1] if driven else np.zeros(3)
        length = float(np.linalg.norm(d))
        if not driven:
            for angle in np.arange(8) * (np.pi / 4):
                ray = np.array([math.cos(angle), math.sin(angle), 0.0])
                if ray_distance(triangles, origins[i], ray) <= clearance_m:
                    x, y = points[i, :2]
                    raise WorldError(
                        f"{what} is within {clearance_m:g} m of the scene's geometry at ({x:.2f}, {y:.2f}) m"
                        f" at {_where(i, actions_json)}",
                        path=world.path,
                    )
        if length > 1e-9:
            dist = ray_distance(triangles, origins[i - 1], d / length)
            if dist <= length + clearance_m:
                x, y = (origins[i - 1] + d / length * dist)[:2]
                raise WorldError(
                    f"{what} crosses the scene's geometry at ({x:.2f}, {y:.2f}) m during "
                    f"{_where(i, actions_json)}",
                    path=world.path,
                )
        if not math.isfinite(ray_distance(triangles, origins[i], down)):
            x, y = points[i, :2]
            raise WorldError(
                f"{what} leaves the scene: no floor below ({x:.2f}, {y:.2f}) m after "
                f"{_where(i, actions_json)}",
                path=world.path,
            )


PATH_CHECK_BLOCK = 2048
"""Poses whose probes :func:`check_path_in_world` builds at once."""


def check_path_in_world(
    world: GridWorld,
    poses: np.ndarray,
    actions_json: list[dict],
    *,
    connected: np.ndarray | None = None,
    clearance_m: float = GENERATED_CLEARANCE_M,
    what: str = TRUE_PATH,
) -> None:
    """Refuse a path that leaves a generated world's free space (:class:`WorldError`, first bad action).

    Every pose, and points every 5 cm along each driven step, need free cells at ``clearance_m`` in
    eight directions around them. Checked ``PATH_CHECK_BLOCK`` poses at a time, in order: the probes
    of a whole 100,000-step route at once would take about 1 GB (407 MiB at 36,001 steps).
    """
    points = np.asarray(poses, dtype=float)[:, :2]
    angles = np.arange(8) * (math.pi / 4)
    ring = np.concatenate([[[0.0, 0.0]], clearance_m * np.column_stack([np.cos(angles), np.sin(angles)])])
    for start in range(0, len(points), PATH_CHECK_BLOCK):
        samples, index = [], []
        for i in range(start, min(start + PATH_CHECK_BLOCK, len(points))):
            if i == 0 or (connected is not None and not connected[i - 1]):
                samples.append(points[i : i + 1])
                index.append(np.array([i]))
                continue
            n = max(1, math.ceil(float(np.hypot(*(points[i] - points[i - 1]))) / 0.05))
            t = np.arange(1, n + 1)[:, None] / n
            samples.append(points[i - 1] + (points[i] - points[i - 1]) * t)
            index.append(np.full(n, i))
        xy = np.concatenate(samples)
        which = np.concatenate(index)
        probe = xy[:, None, :] + ring[None, :, :]
        ok = world.is_free(probe[..., 0], probe[..., 1]).all(axis=1)
        if not ok.all():
            k = int(np.argmin(ok))
            x, y = xy[k]
            raise WorldError(
                f"{what} leaves the generated world's free space at ({x:.2f}, {y:.2f}) m "
                f"({_where(int(which[k]), actions_json)})"
            )
