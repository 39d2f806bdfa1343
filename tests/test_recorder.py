"""`aslam record`: routes, noise model, world generation, rendering, and the command end to end.

Real rendering at 64×48 on short routes, so the whole file takes a few seconds.
"""

from __future__ import annotations

import ctypes.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import one_error_line

from aslam.cli.app import main
from aslam.core import se2
from aslam.data_formats.recording import Recording
from aslam.recorder import noise, routes
from aslam.recorder.config import CameraSpec, NoiseParams, RecordConfig
from aslam.recorder.errors import RouteError, WorldError
from aslam.recorder.world import generate_world

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


@pytest.mark.parametrize("name", ["figure8", "grid"])
def test_other_presets_close(name):
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
        ([1, 2], "JSON object"),
    ],
)
def test_bad_route_files_name_the_file_and_the_entry(tmp_path, doc, needle):
    path = _write_json(tmp_path / "bad.json", doc)
    with pytest.raises(RouteError) as info:
        routes.load_route_file(path)
    message = str(info.value)
    assert message.startswith(str(path)) and needle in message and "\n" not in message


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


@pytest.mark.parametrize("name", ["paper", "figure8", "grid"])
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


def test_world_is_deterministic_per_seed():
    commanded = routes.preset("paper").poses()
    a, b = generate_world(commanded, seed=3), generate_world(commanded, seed=3)
    assert a.panels == b.panels
    assert all(np.array_equal(x, y) for x, y in zip(a.wall_textures, b.wall_textures, strict=True))


# ---------------------------------------------------------------------------------------- rendering


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
        (["--camera-height-m", "3"], "--camera-height-m"),
        (["--laps", "0"], "--laps"),
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
    assert "open" in one_error_line(capsys.readouterr().err)


def test_existing_output_is_refused_without_force(tmp_path, capsys):
    out = tmp_path / "x.mcap"
    out.write_bytes(b"keep me")
    assert main(["record", "-o", str(out), "--size", "32x24"]) == 2
    assert "--force" in one_error_line(capsys.readouterr().err)
    assert out.read_bytes() == b"keep me"


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is None, reason="libosmesa6 is not installed")
def test_osmesa_fallback_renders_the_same_scene(tmp_path):
    """The OSMesa platform (the fallback when EGL cannot start) renders a real recording too.

    The platform is fixed before pyrender is imported, hence a fresh interpreter.
    """
    out = tmp_path / "osmesa.mcap"
    env = {**os.environ, "PYOPENGL_PLATFORM": "osmesa"}
    code = "import sys; from aslam.cli.app import main; sys.exit(main(sys.argv[1:]))"
    args = ["record", "--route", "paper", "--laps", "1", "--size", "48x36", "-o", str(out)]
    done = subprocess.run(
        [sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    frames = [s.image.decode_gray() for s in Recording(out).samples()]
    assert len(frames) == 35
    assert all(frame.std() > 5 for frame in frames)  # real views, not blank buffers
