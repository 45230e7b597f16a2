"""Where planning happens in a scene: its workspace box, the take-off point, and sampled free poses
(the representative poses of the planning benchmark and the feasibility study)."""

from __future__ import annotations

import numpy as np

from flightrecon.planning.distance_field import DistanceField
from flightrecon.scene.levels import scene_levels


def workspace_of(scene, max_height: float) -> np.ndarray:
    """(2, 3) box the candidates must lie in: the room box of a procedural scene; else the mesh's
    horizontal extent from its floor up to its ceiling, or `max_height` above the floor where the
    scene has no ceiling (open scans: their bounds end at the top of the walls)."""
    box = scene.meta.get("room_box") if scene.meta else None
    if box is not None:
        return np.asarray(box, float)
    levels = scene_levels(scene)
    work = np.array(scene.bounds, float)
    work[0, 2] = levels.floor_z
    work[1, 2] = levels.ceiling_z if levels.ceiling_z is not None else levels.floor_z + max_height
    return work


def start_position(scene, takeoff_height: float) -> np.ndarray:
    """The hover point above the scene's spawn (procedural scenes keep a free column there); for
    other scenes, above the center of the floor."""
    spawn = scene.meta.get("spawn") if scene.meta else None
    if spawn is None:
        lo, hi = scene.bounds
        spawn = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, scene_levels(scene).floor_z]
    return np.asarray(spawn, float) + np.array([0.0, 0.0, takeoff_height])


def sample_free_poses(field: DistanceField, workspace: np.ndarray, n: int, clearance: float, seed: int,
                      z_range: tuple[float, float] = (0.8, 1.8)) -> tuple[np.ndarray, np.ndarray]:
    """`n` positions with at least `clearance` on `field` (inside the workspace, heights in
    `z_range` above its floor) and random headings; fewer if the scene has too little free space."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(workspace, float)
    zl, zh = lo[2] + z_range[0], min(lo[2] + z_range[1], hi[2])
    found = np.zeros((0, 3))
    for _ in range(50):
        cand = rng.uniform([lo[0], lo[1], zl], [hi[0], hi[1], zh], (max(4 * n, 64), 3))
        found = np.concatenate([found, cand[field.distance(cand) >= clearance]])
        if len(found) >= n:
            break
    found = found[:n]
    return found, rng.uniform(-np.pi, np.pi, len(found))
