"""The scripted survey flight: take off, fly a loop of waypoints through the room, capture RGB-D.

Waypoints lie on rays from the take-off point (above scene meta 'spawn', kept free of furniture by the
procedural scenes, or the room center; the nearest safe point when that one is not: takeoff.py) at
its height, one ray per heading. Each ray
is walked outward on the scene's distance field and stops where the drone's body radius plus the
planner's safety margin would no longer fit, or at OUTER_SHARE of the way to the walls, so the straight leg from
the center to every waypoint is clear. Consecutive waypoints are joined by a straight leg when that
leg keeps the same clearance, otherwise through the center; the loop ends over the center. Legs are rest-to-rest moves within the
planner's speed, acceleration, jerk and yaw limits. At every waypoint the drone settles (arrival
detection) and captures HEADINGS frames, turning in equal steps from the outward heading (with 8,
consecutive frames overlap by half a 90-degree field of view, so a frame held out for evaluation is
seen by its neighbours, except near the top and bottom of its central columns: a level camera turned
by 45 degrees sees a point at elevation e only where tan(e) <= 0.53 (4:3 frames), the held-out one up to
0.75, so nearby ceiling and floor there count on other waypoints, and 2.5% of office0's frame 44 is seen
by no other frame; the old 2 headings, outward and back, left held-out views largely unseen). The
frames go to an RGB-D dataset (flightrecon.dataset) with the flown trajectory. A contact with the
scene after take-off stops the survey with an error (the dataset keeps the frames before it), unless
sim.on_contact is "continue": then the contacts are counted and listed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from flightrecon.config import ScenarioConfig, to_toml
from flightrecon.dataset import DatasetWriter
from flightrecon.errors import DataError, SceneError
from flightrecon.fileio import write_text
from flightrecon.planning.distance_field import DistanceField
from flightrecon.rig import build_rig
from flightrecon.scene.types import Scene

N_RAYS = 8
WALL_KEEP = 0.4  # waypoints stay this much farther from the room box than the clearance demands (m)
OUTER_SHARE = 0.65  # of the way to the walls: outward views keep some context, not just a wall
MIN_RADIUS = 0.3  # rays that cannot go this far from the center get no waypoint
HEADINGS = 8  # captures per waypoint, equally spaced in yaw starting outward


@dataclass(frozen=True)
class Waypoint:
    position: np.ndarray
    yaws: tuple[float, ...]  # headings of the captures taken here


def scene_distance_field(scene: Scene, cfg: ScenarioConfig, free_point: np.ndarray) -> DistanceField:
    """Ground-truth field of the room; voxels not connected to `free_point` are solid."""
    pad = cfg.required_clearance + 2 * cfg.planner.voxel_size
    bounds = scene.bounds + np.array([[-pad], [pad]])
    return DistanceField.from_mesh(scene.trimesh, cfg.planner.voxel_size, bounds,
                                   free_seeds=np.asarray(free_point, float)[None], signed=False)


def _clear(field: DistanceField, a: np.ndarray, b: np.ndarray, required: float) -> bool:
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / (0.25 * field.voxel_size))) + 1)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    return bool(field.distance(pts).min() >= required)


def survey_waypoints(scene: Scene, cfg: ScenarioConfig, field: DistanceField, center: np.ndarray,
                     headings: int = HEADINGS) -> list[Waypoint]:
    """The loop of capture points (see the module doc), starting and ending over `center`, the
    take-off point (rig.takeoff: its clearance is checked there)."""
    required = cfg.required_clearance
    room = np.asarray(scene.meta.get("room_box", scene.bounds), float)
    step = 0.5 * field.voxel_size
    points = []
    for k in range(N_RAYS):
        theta = 2 * math.pi * k / N_RAYS
        u = np.array([math.cos(theta), math.sin(theta), 0.0])
        # Farthest distance along the ray inside the room box, less the kept margin.
        with np.errstate(divide="ignore"):
            limits = [((room[1, i] if u[i] > 0 else room[0, i]) - center[i]) / u[i]
                      for i in range(2) if abs(u[i]) > 1e-9]
        r_room = min(limits) - required - WALL_KEEP
        radii = np.arange(0.0, max(r_room, 0.0) + 1e-9, step)
        ok = field.distance(center + radii[:, None] * u) >= required
        r = radii[np.argmin(ok)] - step if not ok.all() else (radii[-1] if len(radii) else 0.0)
        r = min(r, OUTER_SHARE * max(r_room, 0.0))
        if r >= MIN_RADIUS:
            points.append((center + r * u, theta))
    if not points:
        raise SceneError(f"scene '{scene.name}': no survey waypoint has {required:.2f} m clearance around the "
                         "take-off point")
    route: list[Waypoint] = []
    prev = center
    for p, theta in points:
        if not _clear(field, prev, p, required):
            route.append(Waypoint(center, ()))
        route.append(Waypoint(p, tuple(theta + 2 * math.pi * j / headings for j in range(headings))))
        prev = p
    route.append(Waypoint(center, ()))  # back over the take-off spot: the ray legs are clear
    return route


@dataclass
class SurveyResult:
    dataset: Path
    frames: int
    flight_time: float
    contacts: int
    min_clearance: float  # after take-off (m between the drone's enclosing sphere and the scene)
    unsettled: int


def run_survey(cfg: ScenarioConfig, out_dir: str | Path, progress: Callable[[str], None] = print,
               headings: int = HEADINGS) -> SurveyResult:
    """Fly the survey in `cfg`'s scene and write the dataset to `out_dir` (`headings` captures per waypoint)."""
    from flightrecon.sim.flight import Flight
    from flightrecon.sim.safety import ClearanceMonitor, FlightContact

    out_dir = Path(out_dir)
    progress(f"scene {cfg.scene.name}: building the world and distance field")
    rig = build_rig(cfg, truth=False)
    scene, camera, center = rig.scene, rig.camera, rig.start
    if rig.takeoff.moved:
        progress(rig.takeoff.note)
    field = scene_distance_field(scene, cfg, center)
    route = survey_waypoints(scene, cfg, field, center, headings)
    n_frames = sum(len(w.yaws) for w in route)
    c = cfg.camera
    flight = Flight.from_world(rig.world, cfg, ClearanceMonitor(scene.trimesh, cfg.drone.body_radius))
    writer = DatasetWriter(out_dir, camera.K, c.width, c.height)
    flight.start(rig.takeoff.ground, 0.0)
    progress(f"take-off to {np.round(center, 2).tolist()}; {len(route)} waypoints, {n_frames} frames")
    flight.go_to(center, 0.0)
    unsettled = 0 if flight.wait_until_arrived() else 1
    airborne = len(flight.log)  # clearance is reported from here: on the floor it is negative by design
    flight.stop_on_contact = cfg.sim.on_contact == "stop"
    i = 0
    try:
        for i, wp in enumerate(route):
            for j, yaw in enumerate(wp.yaws or (None,)):
                target_yaw = flight.last_reference.yaw if yaw is None else yaw
                flight.go_to(wp.position, target_yaw)
                if yaw is None:
                    continue
                if not flight.wait_until_arrived():
                    unsettled += 1
                rgb, depth, T_est, T_true = flight.capture(camera)
                writer.add(rgb, depth, T_est, time=flight.time, T_wc_true=T_true)
                progress(f"[{len(writer.frames)}/{n_frames}] waypoint {i + 1}/{len(route)} "
                         f"at {np.round(wp.position, 2).tolist()} yaw {math.degrees(yaw) % 360:.0f} deg, "
                         f"t = {flight.time:.1f} s")
    except FlightContact as exc:
        raise FlightContact(f"the survey stopped on its way to waypoint {i + 1}/{len(route)}: {exc}; {out_dir} keeps "
                            f"the {len(writer.frames)} frames before it. Raise planner.safety_margin, or set "
                            "sim.on_contact = \"continue\" to fly on and count the contacts", exc.event) from None
    finally:
        camera.close()
        if writer.frames:
            writer.close(flight.log.columns())
            write_text(out_dir / "config.toml", to_toml(cfg))
    if not writer.frames:
        raise DataError(f"the survey captured no frames; nothing written to {out_dir}")
    clear = flight.log["clearance"][airborne:]
    result = SurveyResult(out_dir, len(writer.frames), flight.time, len(flight.log.events),
                          float(np.nanmin(clear)) if len(clear) else math.nan, unsettled)
    for e in flight.log.events:
        progress("  " + e.describe())
    return result
