"""`aslam record`: routes, noise model, world generation, rendering, and the command end to end.

Real rendering at 64×48 on short routes, so the whole file takes a few seconds.
"""

from __future__ import annotations

import ctypes.util
import itertools
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import one_error_line
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.app.pipeline import PipelineCounts, still_clocked
from aslam.cli.app import main
from aslam.core import se2
from aslam.core.errors import ConfigError
from aslam.data_formats.recording import Recording
from aslam.recorder import lighting, noise, routes
from aslam.recorder.config import CameraSpec, NoiseModel, NoiseParams, RecordConfig
from aslam.recorder.errors import RouteError, WorldError
from aslam.recorder.record import ACTION_DURATION_NS, plan
from aslam.recorder.world import check_path_in_world, generate_world

SMALL = CameraSpec(width_px=64, height_px=48)
# a closed 2 m × 1 m loop: 6 forwards + 4 turns, 11 keyframes per lap
LOOP = {
    "start": {"x_m": 0, "y_m": 0, "yaw_deg": 0},
    "actions": [
        {"forward_m": 1},
        {"forward_m": 1},
        {"turn_deg": 90},
        {"forward_m": 1},
        {"turn_deg": 90},
        {"forward_m": 1},
        {"forward_m": 1},
        {"turn_deg": 90},
        {"forward_m": 1},
        {"turn_deg": 90},
    ],
}


def _write_json(path: Path, doc) -> Path:
    path.write_text(json.dumps(doc))
    return path


# ------------------------------------------------------------------------------------------ routes


def test_paper_preset_is_a_30_m_rectangle_from_a_corner_that_closes():
    route = routes.preset("paper")
    assert len(route.actions) == 34
    assert sum(a.forward_m > 0 for a in route.actions) == 30
    assert route.length_m == pytest.approx(30.0)
    assert route.is_closed
    poses = route.repeated(2).poses()
    assert len(poses) == 69
    np.testing.assert_allclose(poses[34], poses[0], atol=1e-9)
    np.testing.assert_allclose(poses[-1], poses[0], atol=1e-9)
    xy = route.poses()[:, :2]
    assert xy.min(axis=0) == pytest.approx([0, 0]) and xy.max(axis=0) == pytest.approx([10, 5])


@pytest.mark.parametrize("name", routes.PRESETS)
def test_every_preset_closes(name):
    route = routes.preset(name)
    assert route.is_closed
    assert len(route.repeated(2).actions) == 2 * len(route.actions)


def test_route_json_round_trips(tmp_path):
    route = routes.load_route_file(_write_json(tmp_path / "loop.json", LOOP))
    assert route.is_closed and len(route.poses()) == 11
    again = routes.parse_route(json.loads(route.to_json()))
    np.testing.assert_allclose(again.poses(), route.poses())


@pytest.mark.parametrize(
    ("doc", "needle"),
    [
        ({"actions": [{"forward_m": 1}, {"forward_m": -2}]}, "actions[1]"),
        ({"actions": [{"jump_m": 1}]}, "actions[0]: unknown action 'jump_m'"),
        ({"actions": [{"forward_m": 1, "turn_deg": 3}]}, "actions[0]"),
        ({"actions": []}, "non-empty"),
        ({"start": {"x_m": "a"}, "actions": [{"turn_deg": 1}]}, "start.x_m"),
        ({"actions": [{"kidnap": {"x_m": "a"}}]}, "actions[0]: kidnap.x_m"),
        ({"actions": [{"kidnap": 3}]}, "actions[0]: kidnap"),
        ({"actions": [{"kidnap": {"x_m": 1, "z_m": 2}}]}, "unknown key(s) 'z_m'"),
        ([1, 2], "JSON object"),
        ({"name": 5, "actions": [{"turn_deg": 1}]}, "'name' must be a string, got 5"),
        ({"route": 1, "actions": [{"turn_deg": 1}]}, "(expected 'start', 'actions', 'name')"),
        # an integer beyond any float: OverflowError and "math domain error", exit 70
        ({"actions": [{"forward_m": 10**400}]}, "actions[0]: forward_m must be a number in (0, 1000]"),
        (
            {"actions": [{"forward_m": 1}, {"kidnap": {"yaw_deg": 10**400}}]},
            "kidnap yaw_deg must be a finite",
        ),
        # a kidnap's heading within ±3600° as the start's; NaN was "beyond ±1000 m of the origin"
        ({"actions": [{"forward_m": 1}, {"kidnap": {"yaw_deg": 1e300}}]}, "within ±3600°, got 1e+300"),
        ({"actions": [{"forward_m": 1}, {"kidnap": {"yaw_deg": math.nan}}]}, "within ±3600°, got nan"),
    ],
)
def test_bad_route_files_name_the_file_and_the_entry(tmp_path, doc, needle):
    path = _write_json(tmp_path / "bad.json", doc)
    with pytest.raises(RouteError) as info:
        routes.load_route_file(path)
    message = str(info.value)
    assert message.startswith(str(path)) and needle in message and "\n" not in message


def test_a_key_given_twice_in_a_route_file_is_refused(tmp_path):
    """JSON keeps the last of two equal keys: a second "start" replaced the first in silence."""
    path = tmp_path / "twice.json"
    path.write_text('{"start": {"x_m": 0}, "actions": [{"forward_m": 1}], "start": {"x_m": 5}}')
    with pytest.raises(RouteError, match="key 'start' given twice") as info:
        routes.load_route_file(path)
    assert str(info.value).startswith(str(path))


def test_a_camera_is_at_least_twice_the_near_plane_above_the_floor_and_fps_rounds_halves_up():
    """``--camera-height-m 0.000001`` rendered the lower half of every image black (the floor
    nearer than the 0.05 m near plane is clipped); ``--fps 2.5`` rendered 2 frames an action and
    3.5 rendered 4 (round half to even), where the docs say the nearest whole number."""
    from aslam.recorder.config import CameraSpec

    def height_problems(height_m: float) -> list[str]:
        return [p for p in RecordConfig(camera=CameraSpec(height_m=height_m)).problems() if "height" in p]

    assert height_problems(0.1) == [] and height_problems(2.39) == []
    assert "at least 0.1 m" in height_problems(0.099)[0] and "at least 0.1 m" in height_problems(1e-6)[0]
    assert "below 2.4 m in a generated world" in height_problems(2.4)[0]
    frames = {fps: RecordConfig(fps=fps).frames_per_action for fps in (1.0, 1.49, 1.5, 2.5, 3.5, 120.0)}
    assert frames == {1.0: 1, 1.49: 1, 1.5: 2, 2.5: 3, 3.5: 4, 120.0: 120}


def test_laps_on_an_open_route_are_refused():
    route = routes.parse_route({"actions": [{"forward_m": 1}]})
    assert len(route.repeated(1).actions) == 1
    with pytest.raises(RouteError, match="open"):
        route.repeated(2)


# ------------------------------------------------------------------------------------------- noise


def test_odometry_differs_from_truth_by_about_sigma_per_action():
    commanded = routes.parse_route({"actions": [{"forward_m": 1.0}] * 3000}).poses()
    model = NoiseParams(noise=0.03, drift_deg_per_m=0.5, jitter_m=0.0, jitter_deg=0.0)
    truth, odom = noise.simulate(commanded, model, seed=3)
    true_steps = se2.between(truth[:-1], truth[1:])
    odom_steps = se2.between(odom[:-1], odom[1:])
    relative = np.hypot(*odom_steps[:, :2].T) / np.hypot(*true_steps[:, :2].T) - 1.0
    assert np.std(relative) == pytest.approx(0.03, rel=0.1)
    assert abs(np.mean(relative)) < 0.003
    assert np.std(odom_steps[:, 2]) == pytest.approx(math.radians(0.5), rel=0.1)


def test_turn_noise_scales_the_angle():
    commanded = routes.parse_route({"actions": [{"turn_deg": 90}] * 2000}).poses()
    _, odom = noise.simulate(commanded, NoiseParams(jitter_m=0, jitter_deg=0), seed=4)
    turns = se2.between(odom[:-1], odom[1:])[:, 2]
    assert np.std(turns / (math.pi / 2) - 1.0) == pytest.approx(0.03, rel=0.1)


def test_truth_jitter_is_small_and_does_not_accumulate():
    commanded = routes.preset("paper").repeated(20).poses()
    truth, odom = noise.simulate(commanded, NoiseParams(), seed=5)
    error = np.hypot(*(truth[:, :2] - commanded[:, :2]).T)
    assert error.max() < 5 * 0.05 * math.sqrt(2)
    first, last = error[:100], error[-100:]
    assert abs(first.mean() - last.mean()) < 0.02  # same spread at the end as at the start
    yaw = np.degrees(se2.wrap_angle(truth[:, 2] - commanded[:, 2]))
    assert np.std(yaw) == pytest.approx(1.5, rel=0.15)
    drift = np.hypot(*(odom[-1, :2] - truth[-1, :2]))
    assert drift > 0.5  # odometry does accumulate over 600 m


def test_noise_is_deterministic_per_seed():
    commanded = routes.preset("paper").poses()
    a = noise.simulate(commanded, NoiseParams(), seed=1)
    b = noise.simulate(commanded, NoiseParams(), seed=1)
    c = noise.simulate(commanded, NoiseParams(), seed=2)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[1], c[1])


# ------------------------------------------------------------------------------------------- world


@pytest.mark.parametrize("name", routes.PRESETS)
def test_every_pose_of_the_route_is_in_free_space(name):
    commanded = routes.preset(name).repeated(2).poses()
    world = generate_world(commanded, seed=0)
    truth, _ = noise.simulate(commanded, NoiseParams(), seed=0)
    assert world.is_free(commanded[:, 0], commanded[:, 1]).all()
    assert world.is_free(truth[:, 0], truth[:, 1]).all()
    # and half a metre around each commanded pose (the corridor is 2 m wide)
    for dx, dy in ((0.5, 0), (-0.5, 0), (0, 0.5), (0, -0.5)):
        assert world.is_free(commanded[:, 0] + dx, commanded[:, 1] + dy).all()
    assert len(world.panels) > 20 and len(world.lights_xy) >= 3


def test_aliasing_shares_textures_without_changing_the_layout():
    commanded = routes.preset("paper").poses()
    plain = generate_world(commanded, seed=7, aliasing=0.0)
    full = generate_world(commanded, seed=7, aliasing=1.0)
    half = generate_world(commanded, seed=7, aliasing=0.5)
    np.testing.assert_array_equal(plain.free, full.free)
    assert all(p.texture < 3 for p in full.panels)
    assert not any(p.texture < 3 for p in plain.panels)
    shared = sum(p.texture < 3 for p in half.panels) / len(half.panels)
    assert 0.3 < shared < 0.7
    assert len(full.wall_textures) == 3
    # truly aliased: no door, no unique texture, one floor texture; in between, some of each
    assert full.door_frames == [] and np.unique(full.floor_zone[full.free]).size == 1
    assert np.unique(plain.floor_zone[plain.free]).size > 1
    zones = half.floor_zone[half.free]
    assert 0 < np.mean(zones == 0) < 1 and len(half.door_frames) <= len(plain.door_frames)


def test_world_is_deterministic_per_seed():
    commanded = routes.preset("paper").poses()
    a, b = generate_world(commanded, seed=3), generate_world(commanded, seed=3)
    assert a.panels == b.panels
    assert all(np.array_equal(x, y) for x, y in zip(a.wall_textures, b.wall_textures, strict=True))


# ---------------------------------------------------------------------------------------- rendering


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(st.booleans(), min_size=7, max_size=7), min_size=0, max_size=9))
def test_floor_rectangles_cover_every_free_cell_once(rows):
    from aslam.recorder.render import cell_rectangles

    mask = np.array(rows, dtype=bool).reshape(-1, 7)
    covered = np.zeros(mask.shape, dtype=int)
    for row0, row1, col0, col1 in cell_rectangles(mask):
        assert row0 < row1 and col0 < col1
        covered[row0:row1, col0:col1] += 1
    np.testing.assert_array_equal(covered, mask.astype(int))


def test_a_generated_worlds_floor_is_a_few_rectangles():
    from aslam.recorder.render import cell_rectangles

    world = plan(RecordConfig(route="grid")).world
    assert len(cell_rectangles(world.free)) * 20 < world.free.sum()


def test_the_framebuffer_has_one_sample_per_pixel():
    """pyrender's 4× multisampled framebuffer is asked for one sample (render.import_pyrender)."""
    from aslam.recorder.render import PyrenderRenderer

    world = generate_world(routes.preset("paper").poses(), seed=0)
    with PyrenderRenderer(world, SMALL) as renderer:
        renderer.render(np.array([1.0, 0.0, 0.0]))
        from OpenGL import GL

        inner = renderer._renderer._renderer
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, inner._main_cb_ms)
        samples = GL.glGetRenderbufferParameteriv(GL.GL_RENDERBUFFER, GL.GL_RENDERBUFFER_SAMPLES)
    assert int(samples) == 0


def test_render_is_not_blank_and_places_differ():
    from aslam.recorder.render import PyrenderRenderer

    world = generate_world(routes.preset("paper").poses(), seed=0)
    # one renderer at a time: pyrender's EGL contexts share one display, and deleting one
    # context terminates it for the others
    with PyrenderRenderer(world, SMALL) as renderer:
        a = renderer.render(np.array([1.0, 0.0, 0.0]))
        b = renderer.render(np.array([9.0, 5.0, math.pi]))
        again = renderer.render(np.array([1.0, 0.0, 0.0]))
    assert a.shape == (48, 64, 3) and a.dtype == np.uint8
    assert a.std() > 20 and b.std() > 20
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 20
    np.testing.assert_array_equal(a, again)


def test_a_world_whose_wall_textures_exceed_one_atlas_page_renders_its_later_panels():
    """A route of 800 m or so without revisits (within the 2,000 m a route may drive) has more
    wall texture than OpenGL takes in one texture: the single atlas (2048 × 17,000 rows and more)
    failed at the first frame, ``GLError: invalid value`` (exit 70). Here the world of the paper
    route gets a page's worth of filler textures, then red for every panel, past the first page."""
    import dataclasses

    from aslam.recorder.render import ATLAS_WIDTH, PyrenderRenderer

    most_rows = 16_384  # the largest texture OpenGL 4.1 guarantees, and llvmpipe's limit

    world = generate_world(routes.preset("paper").poses(), seed=0)
    height = world.wall_textures[0].shape[0]
    filler = np.broadcast_to(np.uint8(128), (height, ATLAS_WIDTH - 8, 3))  # one per atlas row
    fillers = [filler] * (most_rows // height + 1)
    red = np.zeros((height, 256, 3), np.uint8)
    red[..., 0] = 255
    world.wall_textures = [*world.wall_textures, *fillers, red]
    world.panels = [dataclasses.replace(p, texture=len(world.wall_textures) - 1) for p in world.panels]
    with PyrenderRenderer(world, SMALL) as renderer:
        materials = [p.material for m in renderer.scene.meshes for p in m.primitives]
        textures = [m.baseColorTexture.source for m in materials if m.baseColorTexture is not None]
        image = renderer.render(np.array([1.0, 0.0, 0.0])).astype(int)
    assert max(t.shape[0] for t in textures) <= most_rows
    red_pixels = (image[..., 0] > 60) & (image[..., 0] > 3 * (image[..., 1] + image[..., 2]))
    assert red_pixels.mean() > 0.2  # the walls on either side


def test_the_order_lights_are_summed_in_does_not_depend_on_earlier_renderers():
    """pyrender sums the point lights in the order of a set, which follows the nodes' hashes.

    They were numbered per process: a sweep worker's second render (or ``record`` called twice)
    numbered its nodes on from the first's, summed the lights in another order and differed from
    a fresh process's render in the last bit of a few pixels. Eight renderers of 9 nodes each
    started their numbers at every residue mod 8 and summed in four orders; numbered per scene, in one.
    """
    from aslam.recorder.render import PyrenderRenderer

    world = generate_world(routes.preset("paper").poses(), seed=0)
    lightings = (lighting.DEFAULT, lighting.lap_lighting(1.0, 2, len(world.lights_xy), seed=1)[1])
    orders = set()
    for _ in range(8):
        with PyrenderRenderer(world, CameraSpec(width_px=16, height_px=12), lightings) as renderer:
            assert len(renderer.scene.nodes) == 9  # meshes, door frames, 2 panel sets, camera, 4 lights
            orders.add(tuple(renderer._light_nodes.index(n) for n in renderer.scene.point_light_nodes))
    assert len(orders) == 1


# -------------------------------------------------------------------------------------- end to end


def test_record_end_to_end_is_readable_and_byte_identical(tmp_path, capsys):
    route = _write_json(tmp_path / "loop.json", LOOP)
    args = ["record", "--route", str(route), "--laps", "2", "--size", "64x48", "--seed", "3"]
    assert main([*args, "-o", str(tmp_path / "a.mcap"), "--contact-sheet", str(tmp_path / "sheet.png")]) == 0
    assert main([*args, "-o", str(tmp_path / "b.mcap")]) == 0
    a, b = (tmp_path / "a.mcap").read_bytes(), (tmp_path / "b.mcap").read_bytes()
    assert a == b
    samples = list(Recording(tmp_path / "a.mcap").samples())  # 21 small samples
    assert len(samples) == 21
    assert [s.stamp_ns for s in samples] == sorted(s.stamp_ns for s in samples)
    meta = Recording(tmp_path / "a.mcap").metadata()
    assert json.loads(meta["route"])["actions"][0] == {"forward_m": 1.0}
    assert json.loads(meta["noise"])["noise"] == 0.03 and meta["seed"] == "3"
    assert json.loads(meta["world"])["kind"] == "generated"
    assert (tmp_path / "sheet.png").stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "b.mcap", "loop.json", "sheet.png"]


def test_fps_renders_intermediate_frames(tmp_path):
    route = _write_json(tmp_path / "short.json", {"actions": [{"forward_m": 1}, {"turn_deg": 90}]})
    out = tmp_path / "v.mcap"
    assert main(["record", "--route", str(route), "--size", "32x24", "--fps", "4", "-o", str(out)]) == 0
    stamps = [s.stamp_ns for s in Recording(out).samples()]
    assert len(stamps) == 2 * 4 + 1
    assert np.diff(stamps).tolist() == [250_000_000] * 8


def test_interrupt_leaves_no_file(tmp_path):
    from aslam.recorder.record import record

    def interrupt(done, total):
        if done == 3:
            raise KeyboardInterrupt

    config = RecordConfig(route=str(_write_json(tmp_path / "loop.json", LOOP)), camera=SMALL)
    with pytest.raises(KeyboardInterrupt):
        record(config, tmp_path / "out.mcap", progress=interrupt)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop.json"]


def _box_room(path: Path) -> Path:
    import trimesh

    room = trimesh.creation.box((6.0, 6.0, 2.5))
    room.invert()  # faces point inwards: a room seen from inside
    room.apply_translation((0.0, 0.0, 1.25))
    room.export(path)
    return path


def test_scene_file_world_renders_and_a_route_through_a_wall_is_refused(tmp_path, capsys):
    scene = _box_room(tmp_path / "room.glb")
    inside = _write_json(tmp_path / "inside.json", {"start": {"x_m": -1}, "actions": [{"forward_m": 1}] * 2})
    out = tmp_path / "room.mcap"
    assert (
        main(["record", "--world", str(scene), "--route", str(inside), "--size", "32x24", "-o", str(out)])
        == 0
    )
    assert out.exists()
    capsys.readouterr()
    through = _write_json(tmp_path / "through.json", {"actions": [{"forward_m": 1}, {"forward_m": 4}]})
    bad_out = tmp_path / "bad.mcap"
    assert main(["record", "--world", str(scene), "--route", str(through), "-o", str(bad_out)]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert str(scene) in err and "action 1" in err and "forward_m" in err
    assert not bad_out.exists()


@pytest.mark.parametrize(
    ("route", "where"),
    [
        ({"start": {"x_m": 2.9}, "actions": [{"turn_deg": 90}]}, "the start pose"),
        ({"actions": [{"forward_m": 1}, {"kidnap": {"x_m": -2.95, "y_m": 1}}, {"turn_deg": 90}]}, "kidnap"),
    ],
)
def test_a_pose_set_down_against_a_scenes_wall_is_refused(tmp_path, capsys, route, where):
    """A start or a kidnap's landing is not driven to, so no segment's ray met the wall it stands
    in: it rendered the wall's inside (nearly uniform frames) and exited 0."""
    scene = _box_room(tmp_path / "room.glb")
    out = tmp_path / "r.mcap"
    args = ["record", "--world", str(scene), "--route", str(_write_json(tmp_path / "r.json", route))]
    assert main([*args, "--size", "32x24", "-o", str(out)]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert "within 0.15 m of the scene's geometry" in err and where in err
    assert not out.exists()


def test_aliasing_with_a_scene_file_is_refused_and_a_jpeg_quality_is_recorded(tmp_path, capsys):
    """``--aliasing`` left a scene file's images as they were, silently; ``--jpeg-quality`` was in no
    metadata (only the images' format said JPEG)."""
    scene = _box_room(tmp_path / "room.glb")
    args = ["record", "--world", str(scene), "--aliasing", "0.5", "-o", str(tmp_path / "a.mcap")]
    assert main(args) == 2
    assert "--aliasing" in one_error_line(capsys.readouterr().err)
    inside = _write_json(tmp_path / "inside.json", {"start": {"x_m": -1}, "actions": [{"forward_m": 1}]})
    out = tmp_path / "j.mcap"
    args = [
        "record",
        "--world",
        str(scene),
        "--route",
        str(inside),
        "--size",
        "32x24",
        "--jpeg-quality",
        "85",
    ]
    assert main([*args, "-o", str(out)]) == 0
    assert json.loads(Recording(out).metadata()["camera"])["jpeg_quality"] == 85


def test_bad_scene_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"not a gltf at all")
    with pytest.raises(WorldError):
        from aslam.recorder.world import load_scene_world

        load_scene_world(bad)
    assert main(["record", "--world", str(bad), "-o", str(tmp_path / "x.mcap")]) == 2
    assert str(bad) in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("option", "needle"),
    [
        (["--size", "64by48"], "--size"),
        (["--size", "2x2"], "--size"),
        (["--aliasing", "1.5"], "--aliasing"),
        (["--noise", "-0.1"], "--noise"),
        (["--fov-deg", "0"], "--fov-deg"),
        (["--jpeg-quality", "0"], "--jpeg-quality"),
        (["--route", "nowhere"], "unknown route preset"),
        (["--route", "missing.json"], "missing.json"),
        (["--route", ""], "unknown route preset ''"),  # not "the current folder is a directory"
        (["--world", ""], "is a directory, not a scene file (.glb, .gltf, .obj)"),
        (["--world", "/"], "/: is a directory, not a scene file"),
        (["--camera-height-m", "3"], "--camera-height-m"),
        (["--laps", "0"], "--laps"),
        (["--jitter-m", "1e300"], "--jitter-m must be at most 10 m"),
        (["--wander-deg", "1e9"], "--wander-deg must be at most 180"),
        (["--size", "100000x1"], "between 8x8 and 4096x4096"),
        (["--size", "2049x2048"], "at most 4,194,304 (2048x2048), the largest image aslam reads"),
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, option, needle):
    out = tmp_path / "x.mcap"
    assert main(["record", "-o", str(out), *option]) == 2
    assert needle in one_error_line(capsys.readouterr().err)
    assert not out.exists()


def test_laps_on_an_open_route_file_exit_2(tmp_path, capsys):
    route = _write_json(tmp_path / "open.json", {"actions": [{"forward_m": 1}]})
    assert main(["record", "-o", str(tmp_path / "x.mcap"), "--route", str(route), "--laps", "2"]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert "open" in err and err.startswith(f"aslam: error: {route}: ")  # the file, not only its stem


def test_existing_output_is_refused_without_force(tmp_path, capsys):
    out = tmp_path / "x.mcap"
    out.write_bytes(b"keep me")
    assert main(["record", "-o", str(out), "--size", "32x24"]) == 2
    assert "--force" in one_error_line(capsys.readouterr().err)
    assert out.read_bytes() == b"keep me"


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None, reason="libosmesa6 is not installed")
def test_a_pyopengl_that_cannot_pass_arrays_is_one_line_saying_what_to_install(monkeypatch):
    """A plain ``pip install`` on Python 3.12 gets pyrender's pin, PyOpenGL 3.1.0, which makes a
    context and then fails pyrender's first texture with a ctypes ArgumentError: exit 70 with a raw
    ctypes message. The renderer makes that call itself on its new context and says what to do.
    (Measured on Python 3.12.1 with 3.1.0: the same ArgumentError from ``glGenTextures(1)``.)"""
    import ctypes

    from OpenGL import GL

    from aslam.recorder.errors import RenderError
    from aslam.recorder.render import _check_pyopengl_calls

    def no_array_handler(_count):
        raise ctypes.ArgumentError("argument 2: TypeError: No array-type handler for type _ctypes.type")

    monkeypatch.setattr(GL, "glGenTextures", no_array_handler)
    with pytest.raises(RenderError, match=r"pip install --no-deps PyOpenGL==3\.1\.10") as info:
        _check_pyopengl_calls()
    assert "cannot pass arrays to OpenGL on Python" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None, reason="libosmesa6 is not installed")
def test_osmesa_fallback_writes_the_same_bytes_as_egl(tmp_path):
    """The OSMesa platform (the fallback when EGL cannot start) renders real views, and the very
    same files as EGL: both are Mesa's rasteriser drawing into a framebuffer object. (Drawn into
    OSMesa's own buffer, as pyrender does, about 2 % of the pixels were a grey level or two off.)

    The platform is fixed before pyrender is imported, hence a fresh interpreter for each.
    """
    code = "import sys; from aslam.cli.app import main; sys.exit(main(sys.argv[1:]))"
    for platform in ("osmesa", "egl"):
        out = tmp_path / f"{platform}.mcap"
        args = ["record", "--route", "paper", "--laps", "1", "--size", "48x36", "-o", str(out)]
        args += ["--contact-sheet", str(tmp_path / f"{platform}.png")]
        done = subprocess.run(
            [sys.executable, "-c", code, *args],
            env={**os.environ, "PYOPENGL_PLATFORM": platform},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
    frames = [s.image.decode_gray() for s in Recording(tmp_path / "osmesa.mcap").samples()]
    assert len(frames) == 35 and all(frame.std() > 5 for frame in frames)  # real views, not blank buffers
    for name in ("{}.mcap", "{}.png"):
        assert (tmp_path / name.format("osmesa")).read_bytes() == (tmp_path / name.format("egl")).read_bytes()


# --------------------------------------------------------------------------- the hard-case knobs

PAPER_LAP = 34


def _samples(path: Path):
    """The recording's samples (the one place these tests read them, for an easy API change)."""
    return Recording(path).samples()


def _metadata(path: Path) -> dict[str, str]:
    return Recording(path).metadata()


def _offsets(truth: np.ndarray, commanded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return truth[:, :2] - commanded[:, :2], np.degrees(se2.wrap_angle(truth[:, 2] - commanded[:, 2]))


def test_wander_is_smooth_bounded_and_differs_between_laps():
    commanded = routes.preset("paper").repeated(3).poses()
    smooth = NoiseParams(jitter_m=0.0, jitter_deg=0.0, wander_m=0.3, wander_deg=5.0)
    truth, odom = noise.simulate(commanded, smooth, seed=41)
    off, yaw = _offsets(truth, commanded)
    assert 0.15 < off.std() < 0.4 and 2.5 < yaw.std() < 8.0
    assert np.hypot(*off.T).max() <= noise.WANDER_LIMIT_M
    # smooth: 1 m apart the offset barely changes (white jitter of the same σ changes by √2 σ)
    assert np.diff(off, axis=0).std() < 0.5 * off.std()
    assert np.diff(yaw).std() < 0.5 * yaw.std()
    white, _ = noise.simulate(commanded, NoiseParams(jitter_m=0.3, jitter_deg=5.0), seed=41)
    white_off, _ = _offsets(white, commanded)
    assert np.diff(white_off, axis=0).std() > 1.2 * white_off.std()
    # every lap wanders its own way
    lap1, lap2 = off[:PAPER_LAP], off[PAPER_LAP : 2 * PAPER_LAP]
    assert np.hypot(*(lap2 - lap1).T).mean() > 0.15
    # odometry still reports the true motion plus noise (a few % of each step)
    true_steps = se2.between(truth[:-1], truth[1:])
    odom_steps = se2.between(odom[:-1], odom[1:])
    assert np.abs(odom_steps[:, :2] - true_steps[:, :2]).max() < 0.2


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    wander_m=st.floats(0.0, 5.0),
    jitter_m=st.floats(0.0, 2.0),
)
def test_true_offset_is_bounded_whatever_the_wander_and_jitter(seed, wander_m, jitter_m):
    commanded = routes.preset("paper").repeated(2).poses()
    model = NoiseParams(jitter_m=jitter_m, wander_m=wander_m, wander_deg=5.0)
    truth, _ = noise.simulate(commanded, model, seed=seed)
    assert np.hypot(*(truth[:, :2] - commanded[:, :2]).T).max() <= noise.MAX_OFFSET_M + 1e-9
    if jitter_m == 0.0:
        assert np.hypot(*(truth[:, :2] - commanded[:, :2]).T).max() <= noise.WANDER_LIMIT_M + 1e-9


def test_wander_has_its_own_random_stream():
    """Turning the wander on adds a smooth offset and leaves the jitter drawn for the seed alone."""
    commanded = routes.preset("paper").repeated(2).poses()
    jittered, _ = noise.simulate(commanded, NoiseParams(jitter_m=0.05, jitter_deg=0.0), seed=2)
    both, _ = noise.simulate(commanded, NoiseParams(jitter_m=0.05, jitter_deg=0.0, wander_m=0.3), seed=2)
    added = both[:, :2] - jittered[:, :2]
    assert added.std() > 0.1
    assert np.diff(added, axis=0).std() < 0.5 * added.std()  # smooth: none of the white jitter


@pytest.mark.parametrize("name", ["paper", "figure8", "grid"])
@pytest.mark.parametrize(
    "model",
    [
        NoiseParams(jitter_m=0.3, jitter_deg=10.0, wander_m=1.0, wander_deg=10.0),
        NoiseParams(noise=0.1, jitter_m=0.0, jitter_deg=0.0, wander_m=0.3, model=NoiseModel.PAPER),
    ],
    ids=["wander-and-jitter", "paper-10%"],
)
def test_the_camera_stays_in_free_space(name, model):
    p = plan(RecordConfig(route=name, seed=3, noise=model))  # plan() itself refuses a path through walls
    truth = p.truth
    for dx, dy in ((0.0, 0.0), (0.05, 0.0), (-0.05, 0.0), (0.0, 0.05), (0.0, -0.05)):
        assert p.world.is_free(truth[:, 0] + dx, truth[:, 1] + dy).all()
    # and the check is real: the same path 1.5 m to the side is refused, naming the options
    moved = truth + np.array([0.0, 1.5, 0.0])
    with pytest.raises(WorldError, match="--wander-m"):
        check_path_in_world(p.world, moved, [a.to_json() for a in p.route.actions])


def test_the_path_check_in_blocks_finds_the_first_bad_point(monkeypatch):
    """Checked a few poses at a time (bounded memory on a 100,000-step route), the same first
    failure as checked at once, and a good path still passes."""
    import aslam.recorder.world as world_module

    p = plan(RecordConfig(route="grid", seed=3))
    actions = [a.to_json() for a in p.route.actions]
    bad = p.truth.copy()
    bad[len(bad) // 2 :, 1] += 1.5  # the second half off the corridor
    with pytest.raises(WorldError) as at_once:
        check_path_in_world(p.world, bad, actions)
    monkeypatch.setattr(world_module, "PATH_CHECK_BLOCK", 3)
    with pytest.raises(WorldError) as in_blocks:
        check_path_in_world(p.world, bad, actions)
    assert str(in_blocks.value) == str(at_once.value)
    check_path_in_world(p.world, p.truth, actions)


def test_a_true_path_that_wanders_out_of_a_scene_is_refused(tmp_path, capsys):
    scene = _box_room(tmp_path / "room.glb")  # walls at ±3 m
    near_wall = _write_json(
        tmp_path / "near.json", {"start": {"x_m": -2, "y_m": 2.75}, "actions": [{"forward_m": 1}] * 4}
    )
    args = ["record", "--world", str(scene), "--route", str(near_wall), "--size", "32x24"]
    assert main([*args, "--jitter-m", "0", "-o", str(tmp_path / "ok.mcap")]) == 0
    capsys.readouterr()
    out = tmp_path / "bad.mcap"
    assert main([*args, "--jitter-m", "2", "--seed", "1", "-o", str(out)]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert str(scene) in err and "true path" in err and "--jitter-m" in err
    assert not out.exists()


def test_lap_lighting_changes_every_lap_and_nothing_at_zero():
    assert lighting.lap_lighting(0.0, 3, 8, seed=1) == (lighting.DEFAULT,) * 3
    laps = lighting.lap_lighting(1.0, 4, 40, seed=1)
    assert laps == lighting.lap_lighting(1.0, 4, 40, seed=1)
    for a, b in itertools.pairwise(laps):
        assert abs(math.log(a.intensity / b.intensity)) >= 2 * lighting.INTENSITY_LOG_RANGE[0] - 1e-9
        assert (
            abs(math.log(a.temperature_k / b.temperature_k)) >= 2 * lighting.TEMPERATURE_LOG_RANGE[0] - 1e-9
        )
        assert a.lights_on != b.lights_on
    off = np.mean([not on for lap in laps for on in lap.lights_on])
    assert 0.3 < off < 0.7
    warm, cool = lighting.tinted_colour(2700.0), lighting.tinted_colour(6500.0)
    assert warm[0] > warm[2] and cool[2] > cool[0]


def _lap_images(path: Path, per_lap: int) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    def bgr(sample) -> np.ndarray:  # the PNG as stored, in colour
        return cv2.imdecode(np.frombuffer(sample.image.data, np.uint8), cv2.IMREAD_COLOR).astype(float)

    images = np.array([bgr(s) for s in _samples(path)])
    return images[:per_lap], images[per_lap : 2 * per_lap]


def test_lighting_change_relights_each_lap(tmp_path):
    route = _write_json(tmp_path / "loop.json", LOOP)
    base = ["record", "--route", str(route), "--laps", "2", "--size", "64x48", "--jitter-m", "0"]
    base += ["--jitter-deg", "0", "--seed", "4"]
    assert main([*base, "-o", str(tmp_path / "same.mcap")]) == 0
    assert main([*base, "--lighting-change", "1", "-o", str(tmp_path / "relit.mcap")]) == 0
    lap1, lap2 = _lap_images(tmp_path / "same.mcap", 10)
    np.testing.assert_array_equal(lap1, lap2)  # same poses, same light: the same images
    lap1, lap2 = _lap_images(tmp_path / "relit.mcap", 10)
    brightness = np.median(lap2.mean(axis=(1, 2, 3)) / lap1.mean(axis=(1, 2, 3)))
    blue_red = [
        np.median(lap[..., 0].mean(axis=(1, 2)) / lap[..., 2].mean(axis=(1, 2))) for lap in (lap1, lap2)
    ]
    assert abs(math.log(brightness)) > 0.2
    assert abs(math.log(blue_red[1] / blue_red[0])) > 0.1
    meta = json.loads(_metadata(tmp_path / "relit.mcap")["lighting"])
    assert meta["change"] == 1.0 and len(meta["laps"]) == 2


def _palette(world, poses: np.ndarray) -> int:
    """Colours (8 levels per channel) covering ≥ 0.2 % of the pixels of views along the route."""
    from aslam.recorder.render import PyrenderRenderer

    with PyrenderRenderer(world, SMALL) as renderer:
        images = np.array([renderer.render(p) for p in poses])
    q = (images // 32).reshape(-1, 3).astype(int)
    counts = np.bincount(q[:, 0] * 64 + q[:, 1] * 8 + q[:, 2], minlength=512) / len(q)
    return int((counts > 0.002).sum())


def test_aliasing_narrows_what_the_camera_sees():
    commanded = routes.preset("paper").poses()
    palettes = [_palette(generate_world(commanded, seed=7, aliasing=a), commanded[::2]) for a in (0, 0.5, 1)]
    assert palettes[0] > palettes[1] > palettes[2]


def test_paper_noise_accumulates_in_the_truth_and_odometry_reports_the_commanded_route():
    commanded = routes.preset("paper").repeated(10).poses()
    model = NoiseParams(noise=0.03, jitter_m=0.0, jitter_deg=0.0, model=NoiseModel.PAPER)
    errors = []
    for seed in range(12):
        truth, odom = noise.simulate(commanded, model, seed=seed)
        np.testing.assert_allclose(odom[:, :2], commanded[:, :2], atol=1e-9)
        np.testing.assert_allclose(se2.wrap_angle(odom[:, 2] - commanded[:, 2]), 0.0, atol=1e-9)
        errors.append(np.hypot(*(truth[:, :2] - commanded[:, :2]).T))
        executed = se2.between(truth[:-1], truth[1:])
        ordered = se2.between(commanded[:-1], commanded[1:])
        forward = ordered[:, 0] > 0.5
        relative = executed[forward, 0] / ordered[forward, 0] - 1.0
        assert np.std(relative) == pytest.approx(0.03, rel=0.25)
    errors = np.array(errors)
    after_one_lap, after_ten = errors[:, PAPER_LAP].mean(), errors[:, -1].mean()
    assert after_ten > 2.0 * after_one_lap > 0.0  # the error accumulates in the truth


def test_paper_noise_world_is_built_around_the_true_path():
    p = plan(RecordConfig(seed=58, noise=NoiseParams(noise=0.05, jitter_m=0, jitter_deg=0, model="paper")))
    drift = np.hypot(*(p.truth[:, :2] - p.route.poses()[:, :2]).T).max()
    assert drift > 0.5  # far enough off the route that a route-only world would not do
    assert p.world.is_free(p.truth[:, 0], p.truth[:, 1]).all()
    np.testing.assert_allclose(p.odometry[:, :2], p.route.poses()[:, :2], atol=1e-9)


def test_kidnap_jumps_the_truth_while_the_odometry_sees_nothing(tmp_path):
    paper = routes.preset("paper").repeated(2)
    route = routes.kidnapped(paper, 44, 20)
    assert route.actions[44].is_kidnap and not route.connected[44]
    assert len(route.actions) == 44 + 1 + (68 - 20) and route.connected.sum() == len(route.actions) - 1
    again = routes.load_route_file(_write_json(tmp_path / "k.json", json.loads(route.to_json())))
    np.testing.assert_allclose(again.poses(), route.poses(), atol=1e-9)
    commanded = route.poses()
    np.testing.assert_allclose(commanded[45], paper.poses()[20], atol=1e-9)
    truth, odom = noise.simulate(commanded, NoiseParams(), seed=31, connected=route.connected)
    np.testing.assert_array_equal(odom[45], odom[44])  # carried: no odometry
    assert np.hypot(*(truth[45, :2] - commanded[45, :2])) < 0.3  # truth is where it was carried
    assert np.hypot(*(truth[45, :2] - truth[44, :2])) > 3.0
    # the jump is not a corridor
    carved = generate_world(commanded, seed=31)
    kidnapped = generate_world(commanded, seed=31, connected=route.connected)
    assert kidnapped.free.sum() < carved.free.sum()


@pytest.mark.parametrize("fps", [None, 3.0])
def test_an_odometry_reset_read_back_is_one_restart_at_its_keyframe(tmp_path, fps):
    """Read back from a recording, ``--odometry-reset-at 7`` is one restart of the stream's count,
    at keyframe 7's frame (with ``--fps`` the frames before it still move in the old frame); the
    same route without it, noise and all, none, though its odometry passes near its origin."""
    route = _write_json(tmp_path / "loop.json", json.loads(routes.parse_route(LOOP).to_json()))
    args = ["record", "--route", str(route), "--laps", "2", "--size", "32x24", "--seed", "3"]
    args += [*(["--fps", str(fps)] if fps else [])]
    for name, extra in (("reset", ["--odometry-reset-at", "7"]), ("plain", [])):
        assert main([*args, *extra, "-o", str(tmp_path / f"{name}.mcap")]) == 0
        clocked = list(still_clocked(_samples(tmp_path / f"{name}.mcap"), PipelineCounts()))
        restarts = [c.sample.odometry_restarts for c in clocked]
        if name == "plain":
            assert restarts[-1] == 0
            continue
        first = restarts.index(1)
        assert restarts[-1] == 1 and first == 7 * int(fps or 1)
        assert [float(v) for v in clocked[first].sample.odometry_pose] == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("fps", [None, 3.0])
def test_a_carry_is_still_time_and_a_drive_is_none(tmp_path, fps):
    """Read back from a recording, the stream's still clock (what tells the estimator a robot may have
    been carried) counts the carry's second and nothing else: not the drive, its turns or their noise."""
    loop = routes.parse_route(LOOP)
    carried = routes.kidnapped(loop, 2, 5)
    route = _write_json(tmp_path / "carried.json", json.loads(carried.to_json()))
    args = ["record", "--route", str(route), "--laps", "2", "--size", "32x24", "--seed", "3"]
    args += ["--noise", "0.05", "--jitter-m", "0.1", "--jitter-deg", "3"]
    assert main([*args, *(["--fps", str(fps)] if fps else []), "-o", str(tmp_path / "a.mcap")]) == 0
    counts = PipelineCounts()
    clock = [clocked.still_ns for clocked in still_clocked(_samples(tmp_path / "a.mcap"), counts)]
    assert counts.samples == len(clock)
    laps_carried = 2  # the route, carried once a lap
    assert clock[-1] == laps_carried * ACTION_DURATION_NS
    rising = np.flatnonzero(np.diff(clock))  # the carries: one action each, its frames held
    assert len(rising) == laps_carried * (fps or 1) and np.all(np.diff(clock) >= 0)
    assert np.count_nonzero(np.diff(rising) > 1) == laps_carried - 1


def test_odometry_reset_restarts_from_zero_and_keeps_the_motion(tmp_path, capsys):
    route = str(_write_json(tmp_path / "loop.json", LOOP))
    plain = plan(RecordConfig(route=route, laps=2, seed=2))
    reset = plan(RecordConfig(route=route, laps=2, seed=2, odometry_reset_at=7))
    np.testing.assert_array_equal(reset.truth, plain.truth)
    np.testing.assert_array_equal(reset.odometry[:7], plain.odometry[:7])
    np.testing.assert_array_equal(reset.odometry[7], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(
        se2.between(reset.odometry[7:-1], reset.odometry[8:]),
        se2.between(plain.odometry[7:-1], plain.odometry[8:]),
        atol=1e-9,
    )
    with pytest.raises(ConfigError, match="--odometry-reset-at"):
        plan(RecordConfig(route=route, laps=2, odometry_reset_at=21))
    assert (
        main(["record", "--route", route, "--odometry-reset-at", "-1", "-o", str(tmp_path / "x.mcap")]) == 2
    )
    assert "--odometry-reset-at" in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize("turn_deg", [180, -180, 270])
def test_a_half_turn_or_more_at_video_rate_turns_the_commanded_way(tmp_path, turn_deg):
    """Between keyframes the truth and odometry both sweep the commanded turn: two headings 180°
    apart do not say which way the robot went, and the shorter way sent them opposite ways."""
    doc = {"start": {"x_m": 0, "y_m": 0, "yaw_deg": 0}, "actions": [{"forward_m": 1}, {"turn_deg": turn_deg}]}
    p = plan(RecordConfig(route=str(_write_json(tmp_path / "u.json", doc)), fps=8, seed=5))
    frames = list(p.frames())
    for poses in ([f.truth_pose for f in frames], [f.odometry_pose for f in frames]):
        steps = se2.wrap_angle(np.diff(np.array(poses)[:, 2]))[8:]  # the turn's frames
        assert np.all(np.sign(steps) == np.sign(turn_deg))
        assert abs(np.sum(steps) - math.radians(turn_deg)) < 0.2  # noise and jitter


def test_every_knob_at_video_rate_is_deterministic_and_in_the_metadata(tmp_path):
    # the 2 m × 1 m loop, carried from its first corner to its third mid-lap, closed so it repeats
    loop = routes.parse_route(LOOP)
    carried = routes.kidnapped(loop, 2, 5)
    assert carried.is_closed
    route = _write_json(tmp_path / "carried.json", json.loads(carried.to_json()))
    args = ["record", "--route", str(route), "--laps", "2", "--size", "32x24", "--seed", "5", "--fps", "3"]
    args += ["--wander-m", "0.2", "--wander-deg", "4", "--lighting-change", "0.7", "--aliasing", "1"]
    args += ["--noise-model", "paper", "--odometry-reset-at", "9"]
    assert main([*args, "-o", str(tmp_path / "a.mcap")]) == 0
    assert main([*args, "-o", str(tmp_path / "b.mcap")]) == 0
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    n_actions = 2 * len(carried.actions)
    samples = list(_samples(tmp_path / "a.mcap"))
    assert len(samples) == 3 * n_actions + 1
    np.testing.assert_allclose(samples[9 * 3].odometry_pose, 0.0, atol=1e-9)  # keyframe 9: reset
    # while carried (action 2), the view holds until the robot is set down
    held = [s.ground_truth_pose for s in samples[6:9]]
    np.testing.assert_allclose(held[1], held[0], atol=1e-6)
    assert np.hypot(*(samples[9].ground_truth_pose[:2] - held[0][:2])) > 0.5
    meta = _metadata(tmp_path / "a.mcap")
    model = json.loads(meta["noise"])
    assert model["model"] == "paper" and model["wander_m"] == 0.2 and model["odometry_reset_at"] == 9
    assert model["jitter_m"] == 0.0  # the paper model's default
    assert json.loads(meta["lighting"])["change"] == 0.7
    assert json.loads(meta["world"])["aliasing"] == 1.0
    assert {"kidnap": {"x_m": 2.0, "y_m": 1.0, "yaw_deg": -180.0}} in json.loads(meta["route"])["actions"]


def test_a_pose_that_no_driven_step_reaches_is_refused(tmp_path, capsys):
    """Only driven steps get corridors: a route that starts with a kidnap would start inside rock."""
    route = _write_json(
        tmp_path / "k.json", {"actions": [{"kidnap": {"x_m": 5, "y_m": 5}}, {"forward_m": 1}]}
    )
    out = tmp_path / "k.mcap"
    assert main(["record", "--route", str(route), "--size", "32x24", "-o", str(out)]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert "the route" in err and "the start pose" in err and not out.exists()


def test_a_ctrl_c_while_pyrender_is_first_imported_interrupts_record_and_leaves_it_whole(tmp_path):
    """trimesh imports its optional dependencies under ``except BaseException``: a Ctrl-C there was
    swallowed, so a library caller's first ``record()`` rendered on to its end (or, inside
    networkx's imports, left every later ``record()`` failing). The signal is held through the
    import and delivered after it. A real SIGINT, raised while trimesh imports networkx, in a
    fresh interpreter (pyrender not yet imported)."""
    script = """
import importlib.abc, signal, sys
from pathlib import Path

class Hook(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == "networkx":
            sys.meta_path.remove(self)
            signal.raise_signal(signal.SIGINT)
        return None

sys.meta_path.insert(0, Hook())
from aslam.recorder.config import CameraSpec, RecordConfig
from aslam.recorder.record import record

out = Path(sys.argv[1])
try:
    record(RecordConfig(laps=1, camera=CameraSpec(32, 24)), out / "a.mcap")
    print("returned")
except KeyboardInterrupt:
    print("interrupted")
record(RecordConfig(laps=1, camera=CameraSpec(32, 24)), out / "b.mcap")
print(sorted(p.name for p in out.iterdir()))
"""
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["interrupted", "['b.mcap']"]
