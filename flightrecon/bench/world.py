"""Scene load + bake (cold and cached), world compile, RGB-D render time; office0 and room0.

Targets (2-core CPU): cached load + compile < 5 s; one 640x480 RGB-D frame < 250 ms. One render
pass yields color and depth together, so the frame time is both.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time

from flightrecon.bench.common import report, time_call


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", nargs="+", default=["office0", "room0"])
    p.add_argument("--repeat", type=int, default=10, help="timed renders per size (median reported)")
    p.add_argument("--load-repeat", type=int, default=3, help="timed cached loads per scene")


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def run(args) -> dict:
    import flightrecon  # noqa: F401  (EGL before mujoco)

    from flightrecon.geometry import camera_pose
    from flightrecon.scenario import load_config
    from flightrecon.scene import load_scene
    from flightrecon.scene.procedural import make_scene
    from flightrecon.scene.source import write_scene_dir
    from flightrecon.sim.camera import RGBDCamera
    from flightrecon.sim.world import bake_scene, build_world

    rows = []
    for name in args.scenes:
        with tempfile.TemporaryDirectory() as tmp:
            cfg = load_config(None, [f'scene.cache_dir="{tmp}"', f'scene.name="{name}"'])
            scene, t_gen = _timed(lambda: make_scene(name))
            mesh = write_scene_dir(scene, f"{tmp}/scene")
            scene, t_load = _timed(lambda: load_scene(mesh))
            baked, t_bake_cold = _timed(lambda: bake_scene(scene, tmp, cfg.scene.collision_voxel))
            _, t_bake_cached = _timed(lambda: bake_scene(scene, tmp, cfg.scene.collision_voxel))
            world, t_build = _timed(lambda: build_world(scene, cfg, with_drone=False))

            def cached_load_compile():
                s = load_scene(mesh)
                return build_world(s, cfg, with_drone=False)

            cached = time_call(cached_load_compile, repeat=args.load_repeat, warmup=0)
            h, w = baked.atlas.image.shape[:2]
            row = {"scene": name, "triangles": len(scene.faces), "vertices": len(scene.vertices),
                   "atlas": f"{w}x{h}", "atlas_MB": round(baked.atlas.image.nbytes / 2**20, 1),
                   "collision_boxes": len(baked.boxes), "generate_s": t_gen, "load_s": t_load,
                   "bake_cold_s": t_bake_cold, "bake_cached_s": t_bake_cached,
                   "compile_s": t_build - t_bake_cached,
                   "cached_load_compile_s": cached["median_s"]}
            center = [0.0, 0.0, 1.3]
            for width, height in ((640, 480), (320, 240)):
                cam = RGBDCamera(world, width, height, 90.0, cfg.camera.near, cfg.camera.far)
                poses = [camera_pose(center, 2 * math.pi * k / 8, 10.0) for k in range(8)]
                k = iter(range(10**9))
                res = time_call(lambda: cam.render(poses[next(k) % len(poses)]), repeat=args.repeat, warmup=2)
                row[f"rgbd_{width}x{height}_ms"] = 1000 * res["median_s"]
                cam.close()
            rows.append(row)
    return report("world", rows, getattr(args, "out", None), extra={
        "targets": "cached_load_compile_s < 5; rgbd_640x480_ms < 250 (one pass gives RGB and depth)"})
