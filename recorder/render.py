"""Rendering a world with pyrender, headless.

Platform: when ``PYOPENGL_PLATFORM`` is not set and there is no ``DISPLAY``, EGL is used (Mesa
renders on the CPU); when EGL's library is missing or its context cannot be created, OSMesa is
tried instead (it needs ``libosmesa6``; ``make sysdeps`` installs it when EGL is missing).  The
platform must be chosen before PyOpenGL is first imported, so :func:`select_platform` runs first.

The scene is kept light for speed: all wall panels share one texture atlas and one draw call (a
world too long for one atlas page, :data:`ATLAS_MAX_HEIGHT`, one more per page), the
floor is one draw call per floor texture (its cells merged into rectangles), the ceiling, light
panels and door frames one each, and a frame is one sample per pixel (:func:`import_pyrender`).  Four
point lights (pyrender's per-pass cap per light type) follow the camera: each frame they sit at the
four ceiling light panels nearest the camera, so a place is lit the same way on every visit —
unless a per-lap :class:`~aslam.recorder.lighting.Lighting` says otherwise (``--lighting-change``):
then the lights' intensity and colour change, and the point lights sit at the nearest panels that
are *on* (off panels do not glow: each distinct on/off set has its own panel mesh, and only the
current one is visible).
"""

from __future__ import annotations

import contextlib
import ctypes.util
import math
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from aslam.recorder.config import NEAR_PLANE_M, CameraSpec
from aslam.recorder.errors import RenderError
from aslam.recorder.lighting import DEFAULT as DEFAULT_LIGHTING
from aslam.recorder.lighting import DEFAULT_COLOUR, Lighting
from aslam.recorder.world import LIGHT_SIZE_M

ATLAS_WIDTH = 2048
ATLAS_PAD = 2
ATLAS_MAX_HEIGHT = 16_384
"""Rows of one atlas page: the largest texture OpenGL 4.1 guarantees, and llvmpipe's limit. A long
route's world has more wall panels than one page holds (an 845 m route without revisits: 2048 × 17,300
rows), which OpenGL refused (``glTexImage2D``: invalid value); they go on further pages instead."""
N_POINT_LIGHTS = 4
AMBIENT = 0.28
LIGHT_INTENSITY = 4.5


EGL_PLATFORM_SURFACELESS_MESA = 0x31DD


def _egl_works() -> bool:
    """Whether an EGL display initialises (Mesa's surfaceless platform, or the default display).

    A cheap probe with ctypes (~10 ms, no context): PyOpenGL's platform cannot be changed after it
    is imported, so the fallback to OSMesa must be decided before pyrender is imported.
    """
    name = ctypes.util.find_library("EGL")
    if not name:
        return False
    try:
        egl = ctypes.CDLL(name)
        egl.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        egl.eglTerminate.argtypes = [ctypes.c_void_p]
        displays = []
        if hasattr(egl, "eglGetPlatformDisplay"):
            egl.eglGetPlatformDisplay.restype = ctypes.c_void_p
            egl.eglGetPlatformDisplay.argtypes = [ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
            displays.append(lambda: egl.eglGetPlatformDisplay(EGL_PLATFORM_SURFACELESS_MESA, None, None))
        egl.eglGetDisplay.restype = ctypes.c_void_p
        egl.eglGetDisplay.argtypes = [ctypes.c_void_p]
        displays.append(lambda: egl.eglGetDisplay(None))
        for get_display in displays:
            display = get_display()
            major, minor = ctypes.c_int(), ctypes.c_int()
            if display and egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor)):
                egl.eglTerminate(display)
                return True
    except (OSError, AttributeError):
        return False
    return False


def select_platform() -> str:
    """Choose PyOpenGL's platform before it is imported; returns the platform in use ('' = default).

    An explicit ``PYOPENGL_PLATFORM`` wins; with a ``DISPLAY`` the default (GLX) is kept; otherwise
    EGL when it initialises, else OSMesa when its library is installed, else EGL (whose failure then
    produces an error that says what to install).
    """
    if "PYOPENGL_PLATFORM" in os.environ:
        return os.environ["PYOPENGL_PLATFORM"]
    if os.environ.get("DISPLAY"):
        return ""
    platform = "egl"
    if not _egl_works() and ctypes.util.find_library("OSMesa"):
        platform = "osmesa"
    os.environ["PYOPENGL_PLATFORM"] = platform
    return platform


def camera_matrix(pose: np.ndarray, height_m: float) -> np.ndarray:
    """4×4 camera-to-world pose for pyrender (camera looks down its −z, y up) at an SE(2) pose."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:3, 0] = (s, -c, 0.0)  # camera x: to the robot's right
    m[:3, 1] = (0.0, 0.0, 1.0)  # camera y: up
    m[:3, 2] = (-c, -s, 0.0)  # camera z: backwards
    m[:3, 3] = (x, y, height_m)
    return m


@contextlib.contextmanager
def _signals_after_imports() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP while pyrender is first imported, then deliver them.

    trimesh (under pyrender) imports its optional dependencies under ``except BaseException``: a
    Ctrl-C there was kept in a placeholder, so a library caller's ``record()`` rendered on to its
    end, or, landing inside networkx's own imports, left modules half made and every later
    ``record()`` of the process failing with AttributeError. The command line re-raises what a
    library swallowed at its next checkpoint; a library caller has none. Only in the main thread,
    where Python runs signal handlers, and only for handlers that are Python's (not the default
    action, not ignored); ``sys.modules`` decides whether there is anything to import.
    """
    import signal
    import sys
    import threading

    if "pyrender.renderer" in sys.modules or threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    saved = {}
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        handler = signal.getsignal(signum)
        if callable(handler):
            saved[signum] = handler
            signal.signal(signum, lambda number, _frame: held.append(number))
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        if held:
            signal.raise_signal(held[0])  # to the caller's handler, now the imports are whole


def import_pyrender():
    """pyrender on the platform :func:`select_platform` chose, rendering one sample per pixel.

    pyrender always renders into a 4× multisampled framebuffer and has no setting for it. On Mesa's
    CPU rasteriser that costs a fifth to a third of every frame (a grid world's bare render loop,
    measured side by side: 44–47 frames/s against 52–60 with one sample) for smoother polygon edges
    only — the textures are filtered by their mipmaps either way. Measured on 30 robustness-matrix
    runs rendered both ways, the estimates' precision and recall were the same (one jitter run: one
    more correct claim). So the framebuffer pyrender
    allocates gets one sample (``samples=0``); the bench's bare pyrender loop renders the same way.

    On OSMesa pyrender uses no framebuffer object (its OSMesa platform says it has none) and draws
    into OSMesa's own buffer, where Mesa's rasteriser gave about 2 % of the pixels a grey level or
    two off EGL's (a few edge pixels more). OSMesa's core-profile context has framebuffer objects,
    so it is told so: both platforms then draw into the same framebuffer and write the same bytes.
    """
    select_platform()
    try:
        with _signals_after_imports():
            import pyrender
            import pyrender.renderer
            from pyrender.platforms.osmesa import OSMesaPlatform
    except Exception as err:  # PyOpenGL raises ImportError/AttributeError for missing libraries
        raise RenderError(
            f"cannot load pyrender with PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM', '')!r}: {err}"
        ) from err
    module = pyrender.renderer
    if not getattr(module, "_aslam_single_sample", False):
        allocate = module.glRenderbufferStorageMultisample

        def single_sample(target, _samples, *size_and_format):
            return allocate(target, 0, *size_and_format)

        module.glRenderbufferStorageMultisample = single_sample
        module._aslam_single_sample = True
        module._aslam_stock_allocate = allocate  # for bench/record_bench.py's stock-pyrender figure
    OSMesaPlatform.supports_framebuffers = lambda _platform: True
    return pyrender


def _check_pyopengl_calls() -> None:
    """RenderError, one line saying what to install, where PyOpenGL cannot pass an array to OpenGL.

    pyrender pins PyOpenGL 3.1.0, whose ctypes handlers predate Python 3.12: a plain ``pip install``
    there makes a context, then fails pyrender's first texture with a ctypes ArgumentError, which
    was exit 70 ("a bug") with a raw ctypes message. The same call, made here on the new context.
    """
    import platform
    from importlib.metadata import version

    from OpenGL import GL

    try:
        GL.glDeleteTextures([GL.glGenTextures(1)])
    except ctypes.ArgumentError as err:
        raise RenderError(
            f"PyOpenGL {version('PyOpenGL')} cannot pass arrays to OpenGL on Python"
            f" {platform.python_version()} (a ctypes ArgumentError in glGenTextures): install a newer"
            " one, `pip install --no-deps PyOpenGL==3.1.10` (pyrender pins 3.1.0; pip reports the pin"
            " as a conflict)"
        ) from err


# ----------------------------------------------------------------------------- generated worlds


def _atlas(
    textures: list[np.ndarray],
) -> tuple[list[np.ndarray], list[tuple[int, tuple[float, float, float, float]]]]:
    """Shelf-pack equal-height textures into pages of at most ``ATLAS_MAX_HEIGHT`` rows; returns the
    pages and each texture's (page, (u0, v0, u1, v1)). A world that fits one page gets exactly the
    one atlas it always had."""
    th = max(t.shape[0] for t in textures)
    row_h = th + 2 * ATLAS_PAD
    places = []
    page = x = y = 0
    for t in textures:
        w = t.shape[1] + 2 * ATLAS_PAD
        if x + w > ATLAS_WIDTH:
            x, y = 0, y + row_h
            if y + row_h > ATLAS_MAX_HEIGHT:
                page, y = page + 1, 0
        places.append((page, x, y))
        x += w
    heights = [0] * (page + 1)
    for page, _x, y in places:
        heights[page] = max(heights[page], y + row_h)
    atlases = [np.zeros((height, ATLAS_WIDTH, 3), np.uint8) for height in heights]
    rects = []
    for t, (page, x, y) in zip(textures, places, strict=True):
        padded = np.pad(
            t, ((ATLAS_PAD, row_h - t.shape[0] - ATLAS_PAD), (ATLAS_PAD, ATLAS_PAD), (0, 0)), mode="edge"
        )
        atlases[page][y : y + row_h, x : x + padded.shape[1]] = padded
        x0, y0 = x + ATLAS_PAD, y + ATLAS_PAD
        height = heights[page]
        # pyrender flips images on upload: v = 1 is the image's top row
        rects.append(
            (
                page,
                (
                    x0 / ATLAS_WIDTH,
                    1.0 - (y0 + t.shape[0]) / height,
                    (x0 + t.shape[1]) / ATLAS_WIDTH,
                    1.0 - y0 / height,
                ),
            )
        )
    return atlases, rects


def _quads(corners: np.ndarray, normals: np.ndarray, uvs: np.ndarray):
    """Arrays for a primitive of quads: corners (n, 4, 3) counter-clockwise seen from the front."""
    n = len(corners)
    positions = corners.reshape(-1, 3).astype(np.float32)
    normal = np.repeat(normals.astype(np.float32), 4, axis=0)
    uv = uvs.reshape(-1, 2).astype(np.float32)
    base = (np.arange(n) * 4)[:, None]
    faces = (
        np.concatenate([base + np.array([0, 1, 2]), base + np.array([0, 2, 3])], axis=1)
        .reshape(-1, 3)
        .astype(np.uint32)
    )
    return positions, normal, uv, faces


def cell_rectangles(mask: np.ndarray) -> np.ndarray:
    """Disjoint rectangles ``(row0, row1, col0, col1)`` (ends exclusive) covering ``mask``'s cells.

    Each row's runs of cells, a run carried down while the next row has the very same run. Fewer,
    larger quads are far fewer triangles for the rasteriser (a grid world's floor and ceiling: 8,900
    triangles → 70); the texture coordinates are the same affine function of position either way.
    """
    rectangles: list[tuple[int, int, int, int]] = []
    open_runs: dict[tuple[int, int], int] = {}  # run (col0, col1) → the row it started on
    padded = np.zeros((mask.shape[0] + 1, mask.shape[1] + 2), dtype=np.int8)
    padded[:-1, 1:-1] = mask
    for row, cells in enumerate(padded):
        edges = np.flatnonzero(np.diff(cells))
        runs = set(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))
        for run, start in list(open_runs.items()):
            if run not in runs:
                rectangles.append((start, row, *run))
                del open_runs[run]
        for run in sorted(runs - open_runs.keys()):
            open_runs[run] = row
    return np.array(sorted(rectangles), dtype=np.int64).reshape(-1, 4)


def _cell_quads(world, mask: np.ndarray, z: float, up: bool):
    """Horizontal quads over the cells of ``mask`` at height ``z``, facing up or down."""
    row0, row1, col0, col1 = cell_rectangles(mask).T
    x0 = world.origin_xy[0] + col0 * world.cell_m
    y0 = world.origin_xy[1] + row0 * world.cell_m
    x1 = world.origin_xy[0] + col1 * world.cell_m
    y1 = world.origin_xy[1] + row1 * world.cell_m
    zz = np.full_like(x0, z)
    corners = np.stack(
        [
            np.stack([x0, y0, zz], -1),
            np.stack([x1, y0, zz], -1),
            np.stack([x1, y1, zz], -1),
            np.stack([x0, y1, zz], -1),
        ],
        axis=1,
    )
    if not up:
        corners = corners[:, ::-1]
    normals = np.tile([0.0, 0.0, 1.0 if up else -1.0], (len(x0), 1))
    uvs = corners[..., :2] / 2.0  # textures repeat every 2 m
    return _quads(corners, normals, uvs)


def _primitive(pyrender, arrays, material):
    positions, normals, uvs, faces = arrays
    return pyrender.Primitive(
        positions=positions, normals=normals, texcoord_0=uvs, indices=faces, material=material
    )


def _textured(pyrender, image: np.ndarray, *, emissive: float = 0.0):
    texture = pyrender.Texture(source=image, source_channels="RGB")
    return pyrender.MetallicRoughnessMaterial(
        baseColorTexture=texture,
        metallicFactor=0.0,
        roughnessFactor=0.9,
        emissiveFactor=(emissive, emissive, emissive),
    )


_NODE_CLASS = None


def _add(scene, pyrender, *, pose=None, **what):
    """Add a node whose hash is its number in ``scene`` (the nodes added before it), not its address.

    pyrender keeps nodes in sets and sums the lights in set order; with address-based hashes that
    order (and so the last bit of some pixels) changes from run to run.  Numbers make the order,
    and the images, the same on every run; numbered per scene, not per process, so a second
    render in the same process (a sweep worker's) is the same as the first.
    """
    global _NODE_CLASS
    if _NODE_CLASS is None:

        class SequencedNode(pyrender.Node):  # type: ignore[name-defined]  # a module passed in, not imported
            def __init__(self, sequence: int, **kwargs):
                super().__init__(**kwargs)
                self._sequence = sequence

            def __hash__(self) -> int:
                return self._sequence

        _NODE_CLASS = SequencedNode
    node = _NODE_CLASS(len(scene.nodes), matrix=np.eye(4) if pose is None else pose, **what)
    scene.add_node(node)
    return node


def light_panel_primitives(world, pyrender, on=None, emissive=(1.0, 1.0, 1.0)):
    """Ceiling light panels: glowing where ``on`` (default: all), plain grey where off."""
    on = np.ones(len(world.lights_xy), dtype=bool) if on is None else np.asarray(on, dtype=bool)
    h = world.height_m
    out = []
    for lit in (True, False):
        mask = on if lit else ~on
        if not mask.any():
            continue
        half = 0.5 * LIGHT_SIZE_M
        lx, ly = world.lights_xy[mask, 0], world.lights_xy[mask, 1]
        z = np.full_like(lx, h - 0.01)
        c = np.stack(
            [
                np.stack([lx - half, ly - half, z], -1),
                np.stack([lx - half, ly + half, z], -1),
                np.stack([lx + half, ly + half, z], -1),
                np.stack([lx + half, ly - half, z], -1),
            ],
            axis=1,
        )
        glow = np.full((8, 8, 3), 255 if lit else 150, np.uint8)
        glow[0, :] = glow[-1, :] = glow[:, 0] = glow[:, -1] = 170 if lit else 110  # a darker rim
        uv = np.tile([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]], (len(lx), 1, 1))
        material = _textured(pyrender, glow, emissive=1.0)
        material.emissiveFactor = np.asarray(emissive if lit else (0.0, 0.0, 0.0), dtype=float)
        out.append(_primitive(pyrender, _quads(c, np.tile([0.0, 0.0, -1.0], (len(lx), 1)), uv), material))
    return out


def build_generated_scene(world, pyrender, *, light_panels: bool = True):
    """pyrender.Scene of a :class:`~aslam.recorder.world.GridWorld`; returns (scene, light positions).

    ``light_panels=False`` leaves the ceiling light panels out (the renderer adds one set per
    lighting, see :class:`PyrenderRenderer`).
    """
    scene = pyrender.Scene(ambient_light=(AMBIENT, AMBIENT, AMBIENT), bg_color=(0, 0, 0))
    atlases, rects = _atlas(world.wall_textures)
    # per atlas page: the corners, normals and texture coordinates of the panels textured from it
    quads: list[tuple[list, list, list]] = [([], [], []) for _ in atlases]
    h = world.height_m
    for p in world.panels:
        (x0, y0), (x1, y1) = p.p0, p.p1
        page, (u0, v0, u1, v1) = rects[p.texture]
        corners, normals, uvs = quads[page]
        corners.append([[x0, y0, 0.0], [x1, y1, 0.0], [x1, y1, h], [x0, y0, h]])
        normals.append([p.normal[0], p.normal[1], 0.0])
        ue = u0 + (u1 - u0) * p.u1
        uvs.append([[u0, v0], [ue, v0], [ue, v1], [u0, v1]])
    primitives = [
        _primitive(
            pyrender, _quads(np.array(corners), np.array(normals), np.array(uvs)), _textured(pyrender, atlas)
        )
        for atlas, (corners, normals, uvs) in zip(atlases, quads, strict=True)
        if corners
    ]
    for k, image in enumerate(world.floor_textures):
        mask = world.free & (world.floor_zone == k)
        if mask.any():
            primitives.append(
                _primitive(pyrender, _cell_quads(world, mask, 0.0, True), _textured(pyrender, image))
            )
    primitives.append(
        _primitive(
            pyrender, _cell_quads(world, world.free, h, False), _textured(pyrender, world.ceiling_texture)
        )
    )
    if light_panels and len(world.lights_xy):
        primitives.extend(light_panel_primitives(world, pyrender))
    _add(scene, pyrender, mesh=pyrender.Mesh(primitives=primitives))
    if world.door_frames:
        _add(scene, pyrender, mesh=_door_frames_mesh(world.door_frames, pyrender))
    return scene, world.lights_xy


def _door_frames_mesh(doors, pyrender):
    """One mesh of door frames (two jambs and a lintel per door) standing 4 cm off the wall."""
    import trimesh

    from aslam.recorder.world import DOOR_HEIGHT_M

    boxes = []
    t, depth = 0.07, 0.04
    for a, b, n in doors:
        a, b, n = np.array(a), np.array(b), np.array(n)
        d = (b - a) / np.linalg.norm(b - a)
        yaw = math.atan2(d[1], d[0])
        for centre, length, height, z0 in (
            (a - d * t / 2, t, DOOR_HEIGHT_M + t, 0.0),
            (b + d * t / 2, t, DOOR_HEIGHT_M + t, 0.0),
            ((a + b) / 2, np.linalg.norm(b - a) + 2 * t, t, DOOR_HEIGHT_M),
        ):
            box = trimesh.creation.box((float(length), depth, height))
            m = np.eye(4)
            c, s = math.cos(yaw), math.sin(yaw)
            m[:2, :2] = [[c, -s], [s, c]]
            m[:3, 3] = (*(centre + n * depth / 2), z0 + height / 2)
            box.apply_transform(m)
            boxes.append(box)
    merged = trimesh.util.concatenate(boxes)
    material = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=(0.93, 0.91, 0.86, 1.0), metallicFactor=0.0, roughnessFactor=0.8
    )
    return pyrender.Mesh.from_trimesh(merged, material=material, smooth=False)


def build_file_scene(world, pyrender):
    """pyrender.Scene of a loaded scene file, with ambient light; the point lights follow the camera."""
    scene = pyrender.Scene(ambient_light=(0.35, 0.35, 0.35), bg_color=(0, 0, 0))
    graph = world.scene.graph
    for name in sorted(graph.nodes_geometry):
        transform, geometry = graph[name]
        mesh = world.scene.geometry[geometry]
        if hasattr(mesh, "faces") and len(mesh.faces):
            _add(
                scene,
                pyrender,
                mesh=pyrender.Mesh.from_trimesh(mesh, smooth=False),
                pose=np.asarray(transform),
            )
    return scene, None


# ------------------------------------------------------------------------------------- renderer


class PyrenderRenderer:
    """Renders SE(2) camera poses of one world into RGB images, in this process."""

    def __init__(
        self, world, camera: CameraSpec, lightings: Sequence[Lighting] = (DEFAULT_LIGHTING,)
    ) -> None:
        pyrender = import_pyrender()
        self._pyrender = pyrender
        self.camera = camera
        self._panel_nodes: dict[tuple, Any] = {}
        if getattr(world, "kind", "") == "generated":
            self.scene, self._lights_xy = build_generated_scene(world, pyrender, light_panels=False)
            self._light_z = world.height_m - 0.25
            self._world = world
            for lighting in lightings:  # built up front, in order, so node hashes are deterministic
                self._panels_for(lighting)
        else:
            self.scene, self._lights_xy = build_file_scene(world, pyrender)
            self._light_z = camera.height_m + 0.8
        self._ambient = np.array(self.scene.ambient_light, dtype=float)
        self._lighting: Lighting | None = None
        self._on_xy = self._lights_xy
        self._intensity = LIGHT_INTENSITY
        cam = pyrender.PerspectiveCamera(
            yfov=camera.yfov_rad,
            aspectRatio=camera.width_px / camera.height_px,
            znear=NEAR_PLANE_M,
            zfar=80.0,
        )
        self._camera_node = _add(self.scene, pyrender, camera=cam)
        n_lights = N_POINT_LIGHTS if self._lights_xy is not None else 1
        if self._lights_xy is not None:
            n_lights = min(N_POINT_LIGHTS, max(1, len(self._lights_xy)))
        self._light_nodes = [
            _add(
                self.scene,
                pyrender,
                light=pyrender.PointLight(color=(1.0, 0.97, 0.9), intensity=LIGHT_INTENSITY),
            )
            for _ in range(n_lights)
        ]
        try:
            self._renderer = pyrender.OffscreenRenderer(camera.width_px, camera.height_px)
        except Exception as err:
            platform = os.environ.get("PYOPENGL_PLATFORM", "")
            if platform == "egl":
                hint = " (try PYOPENGL_PLATFORM=osmesa with libosmesa6 installed)"
            elif platform == "osmesa" and "OSMesaCreateContextAttribs" in str(err):
                # pyrender pins PyOpenGL 3.1.0, whose OSMesa binding predates what pyrender calls.
                hint = " (OSMesa needs PyOpenGL >= 3.1.5: `pip install --no-deps PyOpenGL==3.1.10`)"
            else:
                hint = " (install libegl-mesa0 or libosmesa6; `make sysdeps` does it)"
            raise RenderError(
                f"cannot create an OpenGL context with platform {platform!r}: {err}{hint}"
            ) from err
        _check_pyopengl_calls()
        self._flags = pyrender.RenderFlags.NONE

    def _panel_key(self, lighting: Lighting) -> tuple:
        n = 0 if self._lights_xy is None else len(self._lights_xy)
        on = lighting.lights_on if lighting.lights_on is not None else (True,) * n
        emissive: tuple[float, ...]
        if lighting.is_default:
            emissive = (1.0, 1.0, 1.0)
        else:
            peak = max(lighting.colour)
            emissive = tuple(c / peak for c in lighting.colour)
        return tuple(bool(v) for v in on), emissive

    def _panels_for(self, lighting: Lighting):
        """The (hidden until used) light-panel node for ``lighting``'s on/off set and colour."""
        if not len(self._world.lights_xy):
            return None
        key = self._panel_key(lighting)
        if key not in self._panel_nodes:
            on, emissive = key
            primitives = light_panel_primitives(self._world, self._pyrender, on, emissive)
            mesh = self._pyrender.Mesh(primitives=primitives, is_visible=False)
            self._panel_nodes[key] = _add(self.scene, self._pyrender, mesh=mesh)
        return self._panel_nodes[key]

    def _apply_lighting(self, lighting: Lighting) -> None:
        """Switch the scene to ``lighting`` (nothing to do when it is the current one)."""
        if lighting == self._lighting:
            return
        self._lighting = lighting
        if self._panel_nodes:
            visible = self._panels_for(lighting)
            for node in self._panel_nodes.values():
                node.mesh.is_visible = node is visible
        if self._lights_xy is not None and len(self._lights_xy) and lighting.lights_on is not None:
            self._on_xy = self._lights_xy[np.asarray(lighting.lights_on, dtype=bool)]
        else:
            self._on_xy = self._lights_xy
        if lighting.is_default:
            self.scene.ambient_light = self._ambient
            colour, intensity = DEFAULT_COLOUR, LIGHT_INTENSITY
        else:
            tint = np.asarray(lighting.colour) / np.asarray(DEFAULT_COLOUR)
            self.scene.ambient_light = self._ambient * lighting.intensity * tint
            colour, intensity = lighting.colour, LIGHT_INTENSITY * lighting.intensity
        self._intensity = intensity
        for node in self._light_nodes:
            node.light.color = np.asarray(colour, dtype=float)
            node.light.intensity = intensity

    def _place_lights(self, pose: np.ndarray) -> None:
        if self._lights_xy is None or not len(self._lights_xy):
            m = np.eye(4)
            m[:3, 3] = (pose[0], pose[1], self._light_z)
            for node in self._light_nodes:
                self.scene.set_pose(node, m)
            return
        d2 = np.sum((self._on_xy - pose[:2]) ** 2, axis=1)
        nearest = np.argsort(d2, kind="stable")[: len(self._light_nodes)]
        for n, node in enumerate(self._light_nodes):
            # fewer lights on than point lights: the spare ones go dark
            node.light.intensity = self._intensity if n < len(nearest) else 0.0
            if n < len(nearest):
                m = np.eye(4)
                m[:3, 3] = (*self._on_xy[nearest[n]], self._light_z)
                self.scene.set_pose(node, m)

    def render(self, pose: np.ndarray, lighting: Lighting = DEFAULT_LIGHTING) -> np.ndarray:
        """RGB uint8 image ``(height_px, width_px, 3)`` seen from SE(2) pose ``(x_m, y_m, yaw_rad)``
        under ``lighting`` (best one of those given to the constructor, whose panels are ready)."""
        pose = np.asarray(pose, dtype=float)
        self._apply_lighting(lighting)
        self.scene.set_pose(self._camera_node, camera_matrix(pose, self.camera.height_m))
        self._place_lights(pose)
        color, _ = self._renderer.render(self.scene, flags=self._flags)
        return color

    def close(self) -> None:
        self._renderer.delete()

    def __enter__(self) -> PyrenderRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
