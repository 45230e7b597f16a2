"""A take-off the drone can fly: the hover point, the vertical climb to it from the floor, the room.

The default take-off (sim.takeoff_height above the scene's spawn, or above its floor's center) is a
guess that furnished scans break: it lands in a sofa, under a table, or outside the walls of an
L-shaped flat. A take-off is safe when every point of the climb from where the drone rests on the
floor up to the hover point keeps the required clearance (drone.body_radius +
planner.safety_margin) to the scene's true surface (scene.surface_distance), and the hover point lies
in the room's free space (scene.free_space.room_for_takeoff: the empty region around the default point,
or the one that fills the room's box), from which the
drone can reach what it is to map. Near the floor the floor itself may come closer (the drone starts
resting on it): there the requirement is the height over the floor less FLOOR_TOLERANCE, so only
something else near the drone counts. The hover point keeps PLANNER_SLACK planner voxels more: the
planner measures clearance on its voxel map, which may read that much below the truth, and a drone
it judges too close cannot even turn in place ("cannot leave its take-off point"). The drone rests
on ground level within LEVEL_DEG (rays cast down under its body): on a slope it slides into the
scene before it is airborne, which is how a scan flown tilted shows first.

When the default is not safe, the nearest safe hover point of a grid over the flight workspace is
used, and the reason is said; when none is, one error names the keys that change the answer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flightrecon.config import ScenarioConfig
from flightrecon.errors import SceneError
from flightrecon.open3d_import import open3d_module
from flightrecon.scene.free_space import FreeSpace, room_for_takeoff
from flightrecon.scene.surface_distance import SurfaceDistance
from flightrecon.scene.types import Scene

GRID = 0.1  # m between candidate hover points
CLIMB_STEP = 0.01  # m between checked points of a climb
FLOOR_TOLERANCE = 0.05  # m the floor may lie above its detected height (scan noise, rugs)
PLANNER_SLACK = 1.5  # planner voxels (planner.voxel_size) the hover point keeps beyond the required clearance
CHUNK = 256  # candidates whose climbs are checked in one query
LEVEL_DEG = 10.0  # the ground a drone rests on before take-off is level within this
KEYS = ("Change sim.takeoff_height, drone.body_radius, planner.safety_margin, planner.voxel_size or "
        "planner.max_height, or check scene.up_axis (or scene.up_vector) and scene.unit_scale (`flightrecon scene "
        "info` shows the floor, ceiling and workspace)")


@dataclass(frozen=True)
class TakeOff:
    """Where a flight starts: resting on the floor at `ground`, then climbing straight up to `hover`."""

    hover: np.ndarray  # (3,) where the drone hovers after the climb
    ground: np.ndarray  # (3,) where it rests before it, right below `hover`
    default: np.ndarray  # (3,) the hover point sim.takeoff_height above the spawn
    free: FreeSpace  # the room's free space, which holds `hover`
    note: str  # why the default was not used and what was instead; "" when it was

    @property
    def moved(self) -> bool:
        return bool(self.note)


class _Checker:
    """Clearance of climbs and room membership of hover points in one scene."""

    def __init__(self, scene: Scene, cfg: ScenarioConfig, free: FreeSpace, floor_z: float) -> None:
        self.surface = SurfaceDistance(scene.trimesh)
        self.free = free
        self.floor_z = floor_z
        self.rest_z = floor_z + 0.5 * cfg.drone.body_radius  # the drone's center, resting on the floor
        self.body_radius = cfg.drone.body_radius
        self.required = cfg.required_clearance  # on the climb
        self.at_hover = self.required + PLANNER_SLACK * cfg.planner.voxel_size

    def climbs(self, hovers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per hover point (N, 3), at the worst point of its climb: the shortfall (m, <= 0 when
        clear), the height and the distance to the scene."""
        hovers = np.atleast_2d(hovers)
        n = max(2, int(np.ceil((hovers[:, 2].max() - self.rest_z) / CLIMB_STEP)) + 1)
        z = np.linspace(np.full(len(hovers), self.rest_z), hovers[:, 2], n)  # (n, N), spacing <= CLIMB_STEP
        pts = np.stack([np.broadcast_to(hovers[:, 0], z.shape), np.broadcast_to(hovers[:, 1], z.shape), z], -1)
        dist = self.surface.distance(pts.reshape(-1, 3)).reshape(z.shape)
        need = np.minimum(self.required, z - self.floor_z - FLOOR_TOLERANCE)
        short = np.nan_to_num(need - dist, nan=np.inf)
        worst = np.argmax(short, axis=0)
        cols = np.arange(len(hovers))
        return short[worst, cols], z[worst, cols], dist[worst, cols]

    def ground_tilt(self, hovers: np.ndarray) -> np.ndarray:
        """Per hover point (N, 3), the steepest tilt (deg) of the surface the drone rests on before
        its climb: rays cast straight down from the hover point and from four points half a body
        radius around it (a ray through a hole in a scan's floor hits nothing: no slope there)."""
        hovers = np.atleast_2d(hovers)
        r = 0.5 * self.body_radius
        offsets = np.array([[0.0, 0.0, 0.0], [r, 0.0, 0.0], [-r, 0.0, 0.0], [0.0, r, 0.0], [0.0, -r, 0.0]])
        origins = (hovers[:, None, :] + offsets[None]).reshape(-1, 3)
        down = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)
        o3d = open3d_module()
        rays = o3d.core.Tensor(np.ascontiguousarray(np.concatenate([origins, down], 1), np.float32))
        hit = self.surface.raycasting_scene().cast_rays(rays)
        up = np.abs(hit["primitive_normals"].numpy()[:, 2].astype(np.float64))
        tilt = np.where(np.isfinite(hit["t_hit"].numpy()), np.degrees(np.arccos(np.clip(up, 0.0, 1.0))), 0.0)
        return tilt.reshape(len(hovers), len(offsets)).max(axis=1)

    def why_not(self, hover: np.ndarray) -> str:
        """Why `hover` is not a safe take-off, or "" when it is."""
        tilt = float(self.ground_tilt(hover)[0])
        if tilt > LEVEL_DEG:
            return (f"stands over ground tilted {tilt:.0f} deg where the drone would rest before its climb (a "
                    f"take-off needs ground level within {LEVEL_DEG:g} deg: a scan whose up is wrong is tilted)")
        clear = float(self.surface.distance(hover[None])[0])
        if not clear >= self.at_hover:
            return (f"has {clear:.2f} m to the scene, less than the {self.at_hover:.2f} m it needs "
                    f"(drone.body_radius + planner.safety_margin, and {PLANNER_SLACK:g} planner.voxel_size for the "
                    "planner's map)")
        short, z, dist = self.climbs(hover)
        if short[0] > 0:
            return (f"is reached by a climb from the floor that passes {dist[0]:.2f} m from the scene at "
                    f"z = {z[0]:.2f} m, where it needs {dist[0] + short[0]:.2f} m")
        if not self.free.contains(hover)[0]:
            return "is not in the room's free space (it is inside furniture or outside the room's walls)"
        return ""


def _axis(center: float, lo: float, hi: float) -> np.ndarray:
    """Integer GRID steps from `center` (as numbers of steps) that stay within [lo, hi]."""
    return np.arange(np.ceil((lo - center) / GRID - 1e-9), np.floor((hi - center) / GRID + 1e-9) + 1)


def _candidates(default: np.ndarray, workspace: np.ndarray) -> np.ndarray:
    """Grid points of `workspace` (GRID apart, on a grid through `default`), nearest first; ties in
    the grid's fixed order."""
    steps = [_axis(default[i], workspace[0, i], workspace[1, i]) for i in range(3)]
    if any(len(s) == 0 for s in steps):
        return np.zeros((0, 3))
    k = np.stack(np.meshgrid(*steps, indexing="ij"), -1).reshape(-1, 3)
    order = np.argsort(np.sum(k.astype(np.int64) ** 2, axis=1), kind="stable")  # exact integer distances
    return default + GRID * k[order]


def safe_takeoff(scene: Scene, cfg: ScenarioConfig, default: np.ndarray, room: np.ndarray,
                 workspace: np.ndarray) -> TakeOff:
    """The take-off from `default` (the hover point over the spawn) if it is safe, else from the
    nearest safe hover point in `workspace` (the box candidate viewpoints lie in); `room` is the
    room's box (free_space.room_for_takeoff finds the room's free space in it). Raises SceneError when
    no hover point is safe."""
    default, workspace = np.asarray(default, float), np.asarray(workspace, float)
    floor_z = float(default[2] - cfg.sim.takeoff_height)
    free = room_for_takeoff(scene, default, np.asarray(room, float))
    check = _Checker(scene, cfg, free, floor_z)
    why = check.why_not(default)
    hover = default if not why else _nearest_safe(check, _candidates(default, workspace))
    if hover is None:
        lo, hi = (np.round(b, 2).tolist() for b in workspace)
        others = (f"the flight workspace {lo} .. {hi} (the room shrunk by the clearance) is empty" if
                  (workspace[0] > workspace[1]).any() else
                  f"no point {GRID:g} m apart in the flight workspace {lo} .. {hi} has {check.at_hover:.2f} m "
                  f"clearance to the scene, {check.required:.2f} m on its vertical climb from the floor, inside the "
                  "room's free space")
        raise SceneError(
            f"scene '{scene.name}' has no safe take-off point: the default hover point "
            f"{np.round(default, 2).tolist()} (sim.takeoff_height = {cfg.sim.takeoff_height:g} m above the floor "
            f"at z = {floor_z:.2f} m) {why}, and {others}. {KEYS}")
    ground = np.array([hover[0], hover[1], check.rest_z])
    note = ""
    if why:
        note = (f"take-off moved: the default hover point {np.round(default, 2).tolist()} {why}; taking off "
                f"from {np.round(hover, 2).tolist()} instead, {np.linalg.norm(hover - default):.2f} m away, the "
                f"nearest with {check.at_hover:.2f} m clearance, {check.required:.2f} m on its climb from the floor, "
                "in the room's free space")
    return TakeOff(hover.copy(), ground, default.copy(), free, note)


def _nearest_safe(check: _Checker, candidates: np.ndarray) -> np.ndarray | None:
    """The first of `candidates` (nearest first) that is a safe take-off, or None."""
    if not len(candidates):
        return None
    keep = check.free.contains(candidates)
    keep[keep] = check.surface.distance(candidates[keep]) >= check.at_hover
    keep[keep] = check.ground_tilt(candidates[keep]) <= LEVEL_DEG
    ok = candidates[keep]
    for start in range(0, len(ok), CHUNK):
        chunk = ok[start:start + CHUNK]
        short, _, _ = check.climbs(chunk)
        clear = np.flatnonzero(short <= 0)
        if len(clear):
            return chunk[clear[0]]
    return None
