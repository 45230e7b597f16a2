"""Planner speed: full-library feasibility check (target <= 200 ms), share needing OMPL, occupancy update per depth frame.

For each scene, representative poses are sampled in the free space of the ground-truth scene. The
online map is built the way a flight builds it: MuJoCo renders a depth frame at four headings from
every pose, each integrated into the occupancy map (timed), with the drone's body volume marked
free. At each of those headings a streamed frame (planner.look_hz) is timed too, render and update,
at `planner.look_width` and, its peer, at the frame's full size, on a copy of the map. The full
library is then checked from every pose, on the online map and on the ground truth. The CPU time
of one check and the load average are reported too: on a shared machine the wall time alone says
little.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from flightrecon.bench.common import report, time_call
from flightrecon.control.trajectory import FlatState
from flightrecon.geometry import camera_pose
from flightrecon.planning.feasibility import Planner
from flightrecon.planning.poses import sample_free_poses, start_position, workspace_of
from flightrecon.scenario import load_config


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", default="office0,room0", help="comma-separated procedural scenes")
    p.add_argument("--poses", type=int, default=6, help="representative poses per scene")
    p.add_argument("--repeat", type=int, default=3, help="timed library checks per pose")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)


def run(args: argparse.Namespace) -> dict:
    from flightrecon.scene.source import procedural_scene
    from flightrecon.sim.camera import RGBDCamera, reduction_for_width
    from flightrecon.sim.world import build_world

    rows = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        cfg = load_config(None, [f"scene.name={name}"])
        scene = procedural_scene(name, cfg.scene.seed)
        ws = workspace_of(scene, cfg.planner.max_height)
        start = start_position(scene, cfg.sim.takeoff_height)
        t0 = time.perf_counter()
        gt = Planner(load_config(None, [f"scene.name={name}", "planner.use_ground_truth=true"]), ws,
                     scene.trimesh, start_position=start)
        gt_build = time.perf_counter() - t0
        clearance = gt.settings.required_clearance + 0.1
        poses, yaws = sample_free_poses(gt.field, ws, args.poses - 1, clearance, seed=0)
        poses, yaws = np.vstack([start, poses]), np.concatenate([[0.0], yaws])
        online = Planner(cfg, ws, start_position=start)
        world = build_world(scene, cfg, with_drone=False)
        cam = RGBDCamera(world, args.width, args.height, cfg.camera.hfov_deg, cfg.camera.near, cfg.camera.far)
        reduce = reduction_for_width(args.width, args.height, cfg.planner.look_width)
        frame_times, looks = [], {"look": [], "look_full": []}
        for p, y in zip(poses, yaws):
            for k in range(4):
                T = camera_pose(p, y + k * np.pi / 2, cfg.camera.pitch_deg)
                _, depth = cam.render(T)
                state = online.get_state()
                for key, n in (("look", reduce), ("look_full", 1)):
                    t0 = time.perf_counter()
                    _, look_depth = cam.render(T, n)
                    online.integrate(look_depth, cam.intrinsics_at(n), T, body_position=p)
                    looks[key].append(time.perf_counter() - t0)
                    online.set_state(state)
                t0 = time.perf_counter()
                online.integrate(depth, cam.K, T, body_position=p)
                frame_times.append(time.perf_counter() - t0)
        cam.close()
        t0 = time.perf_counter()
        online.field  # noqa: B018  (distance transform of the map, once per step)
        field_time = time.perf_counter() - t0
        for mode, planner in (("online map", online), ("ground truth", gt)):
            checks, cpu, ompl_share, feasible = [], [], [], []
            for p, y in zip(poses, yaws):
                state = FlatState(p, np.zeros(3), np.zeros(3), float(y), 0.0)
                checks.append(time_call(lambda: planner.check_library(state), repeat=args.repeat)["median_s"])
                c0 = time.process_time()
                res = planner.check_library(state)
                cpu.append(time.process_time() - c0)
                ompl_share.append(planner.times.n_ompl / len(res))
                feasible.append(sum(r.feasible for r in res) / len(res))
            rows.append({"scene": name, "world": mode, "poses": len(poses),
                         "check_median_ms": 1e3 * statistics.median(checks),
                         "check_max_ms": 1e3 * max(checks),
                         "check_cpu_median_ms": 1e3 * statistics.median(cpu),
                         "share_ompl": statistics.mean(ompl_share),
                         "share_feasible": statistics.mean(feasible),
                         "occupancy_update_ms": 1e3 * statistics.median(frame_times) if mode == "online map" else "",
                         **{f"{key}_ms": 1e3 * statistics.median(v) if mode == "online map" else ""
                            for key, v in looks.items()},
                         "field_build_ms": 1e3 * (field_time if mode == "online map" else gt_build)})
    return report("plan", rows, getattr(args, "out", None),
                  extra={"target": "check_median_ms <= 200 on 2 cores",
                         "load_average": " ".join(f"{x:.1f}" for x in os.getloadavg()),
                         "frame": f"{args.width}x{args.height}", "library": "default (198)",
                         "look": f"{args.width // reduce}x{args.height // reduce} (planner.look_width "
                                 f"{cfg.planner.look_width}); look_full: {args.width}x{args.height}"})
