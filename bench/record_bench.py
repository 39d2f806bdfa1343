"""Recording speed: keyframes/s of `aslam record` at 320×240 on the paper route, against a bare
pyrender render loop of the same scene measured in the same run.

    python bench/record_bench.py [--laps 4] [--repeats 3] [--size 320x240] [--json]

Three figures per run (best of ``--repeats``, alternating the two loops to share CPU contention):
* ``record end-to-end``: :func:`aslam.recorder.record.record` from config to a finished MCAP file
  (world generation, GL start-up, shader compilation, rendering, PNG encoding, writing);
* ``record loop``: its render → encode → write loop only (reported by ``record``);
* ``bare loop``: the same scene, poses and framebuffer (one sample per pixel, as the recorder asks
  pyrender for: ``aslam.recorder.render.import_pyrender``), only ``scene.set_pose(camera)`` +
  ``renderer.render``;
* ``stock loop``: the bare loop in pyrender's own 4× multisampled framebuffer, for comparison.
The ratio ``record loop / bare loop`` is the recorder's overhead per frame (target ≤ 1.2).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def bare_loop_seconds(p, camera, *, stock: bool = False) -> float:
    """Seconds to render every keyframe of plan ``p`` with nothing but pyrender calls, into the
    recorder's framebuffer (one sample per pixel) or, ``stock``, pyrender's own (4× multisampled)."""
    from aslam.recorder.render import import_pyrender

    pyrender = import_pyrender()
    if not stock:
        return _bare_loop(pyrender, p, camera)
    module = pyrender.renderer
    single = module.glRenderbufferStorageMultisample
    module.glRenderbufferStorageMultisample = module._aslam_stock_allocate
    try:
        return _bare_loop(pyrender, p, camera)
    finally:
        module.glRenderbufferStorageMultisample = single


def _bare_loop(pyrender, p, camera) -> float:
    from aslam.recorder.render import _add, build_generated_scene, camera_matrix

    scene, lights_xy = build_generated_scene(p.world, pyrender)
    cam = pyrender.PerspectiveCamera(
        yfov=camera.yfov_rad, aspectRatio=camera.width_px / camera.height_px, znear=0.05
    )
    cam_node = _add(scene, pyrender, camera=cam)
    for xy in lights_xy[:4]:
        m = np.eye(4)
        m[:3, 3] = (*xy, p.world.height_m - 0.25)
        _add(scene, pyrender, light=pyrender.PointLight(intensity=4.5), pose=m)
    renderer = pyrender.OffscreenRenderer(camera.width_px, camera.height_px)
    try:
        start = time.perf_counter()
        for pose in p.truth:
            scene.set_pose(cam_node, camera_matrix(pose, camera.height_m))
            renderer.render(scene)
        return time.perf_counter() - start
    finally:
        renderer.delete()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--route", default="paper", help="paper, or grid (a generated grid world)")
    parser.add_argument("--laps", type=int, default=None, help="laps (default: the route's own)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = parser.parse_args()

    from aslam.recorder.config import CameraSpec, RecordConfig, parse_size
    from aslam.recorder.record import plan, record

    width, height = parse_size(args.size)
    config = RecordConfig(
        route=args.route, laps=args.laps, seed=0, camera=CameraSpec(width_px=width, height_px=height)
    )
    p = plan(config)
    n = len(p.truth)
    best = {"end": float("inf"), "loop": float("inf"), "bare": float("inf"), "stock": float("inf")}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            best["bare"] = min(best["bare"], bare_loop_seconds(p, config.camera))
            best["stock"] = min(best["stock"], bare_loop_seconds(p, config.camera, stock=True))
            result = record(config, Path(tmp) / "bench.mcap", force=True)
            best["end"] = min(best["end"], result.seconds)
            best["loop"] = min(best["loop"], result.render_seconds)
    if args.json:
        result = {
            "route": args.route,
            "laps": args.laps,
            "keyframes": n,
            "size": f"{width}x{height}",
            "repeats": args.repeats,
            "end_to_end_s": best["end"],
            "loop_s": best["loop"],
            "bare_s": best["bare"],
            "stock_s": best["stock"],
            "end_to_end_keyframes_per_second": n / best["end"],
            "loop_keyframes_per_second": n / best["loop"],
            "bare_keyframes_per_second": n / best["bare"],
            "stock_keyframes_per_second": n / best["stock"],
            "ratio_loop_over_bare": best["loop"] / best["bare"],
            "ratio_end_to_end_over_bare": best["end"] / best["bare"],
        }
        print(json.dumps(result))
        return
    print(
        f"{args.route} route, {args.laps or 'default'} laps, {n} keyframes at {width}x{height},"
        f" best of {args.repeats}"
    )
    for name, key in (
        ("record end-to-end", "end"),
        ("record loop", "loop"),
        ("bare pyrender loop", "bare"),
        ("stock pyrender (4× MSAA) loop", "stock"),
    ):
        print(f"  {name:<29}: {n / best[key]:6.1f} keyframes/s  ({best[key]:.2f} s)")
    print(f"  ratio record loop / bare loop      : {best['loop'] / best['bare']:.2f}")
    print(f"  ratio record end-to-end / bare loop: {best['end'] / best['bare']:.2f}")


if __name__ == "__main__":
    main()
