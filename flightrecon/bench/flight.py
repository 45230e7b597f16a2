"""Flight cycle speed: physics + control real-time factor, with and without RGB-D frames; tracking RMS.

The drone flies a figure-eight over the scene's take-off spot in the scenario's world (scene
collision boxes included). Real-time factor = simulated seconds / wall seconds, median over repeats; on a shared machine the
CPU-time factor (simulated seconds / this process's CPU seconds, all threads) shows the cost without
waiting for the CPU.
"with frames" renders one RGB-D frame (the scenario's camera size) per simulated second.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from flightrecon.bench.common import report
from flightrecon.scenario import load_config


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="default", help="scenario name or TOML")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--laps", type=float, default=2.0, help="figure-eight laps per run")
    p.add_argument("--period", type=float, default=6.0, help="seconds per lap")
    p.add_argument("--repeat", type=int, default=3)


def run(args: argparse.Namespace) -> dict:
    from flightrecon.control.reference_paths import FigureEight
    from flightrecon.scene.source import scene_from_config
    from flightrecon.sim.camera import RGBDCamera
    from flightrecon.sim.flight import Flight
    from flightrecon.sim.world import build_world
    from flightrecon.rig import takeoff_point

    cfg = load_config(args.scenario, args.overrides)
    scene = scene_from_config(cfg.scene)
    world = build_world(scene, cfg)
    center = takeoff_point(scene, cfg)
    # Inside the furniture-free column of the procedural scenes (0.7 m half side) with the body radius.
    fig8 = FigureEight(center, 0.4, 0.35, args.period, laps=args.laps, ramp=min(2.0, args.period))
    c = cfg.camera
    camera = RGBDCamera(world, c.width, c.height, c.hfov_deg, c.near, c.far)
    flight = Flight.from_world(world, cfg)
    steps_per_frame = int(round(1.0 / flight.control_dt))

    def fly_once(with_frames: bool) -> tuple[float, float, float, int]:
        flight.start(center, 0.0)
        n = int(math.ceil(fig8.duration / flight.control_dt))
        start = len(flight.log)
        frames = 0
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(n):
            flight.step(fig8.sample(k * flight.control_dt))
            if with_frames and (k + 1) % steps_per_frame == 0:
                flight.sync()
                camera.render_named("drone_cam")
                frames += 1
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        sim = n * flight.control_dt
        return sim / wall, sim / cpu, flight.log.slice_from(start).tracking_rms(), frames

    rows = []
    for with_frames in (False, True):
        fly_once(with_frames)  # warm-up (GL context, caches)
        runs = [fly_once(with_frames) for _ in range(args.repeat)]
        rtfs = [r[0] for r in runs]
        rows.append({"mode": f"physics+control{' + 1 RGB-D frame/s' if with_frames else ''}",
                     "rtf_median": float(np.median(rtfs)), "rtf_min": min(rtfs), "rtf_max": max(rtfs),
                     "rtf_cpu_median": float(np.median([r[1] for r in runs])),
                     "frames_per_run": runs[0][3], "tracking_rms_m": runs[0][2]})
    camera.close()
    extra = {"scene": scene.name, "collision_geoms": int(len(world.collision_geom_ids)),
             "physics_hz": 1.0 / cfg.sim.physics_dt, "control_hz": cfg.sim.control_rate_hz,
             "camera": f"{c.width}x{c.height}", "figure_eight": f"{fig8.ax}x{fig8.ay} m, {args.period} s/lap",
             "target": "rtf >= 20 without rendering on 2 cores; tracking RMS < 0.05 m"}
    return report("flight", rows, getattr(args, "out", None), extra)
