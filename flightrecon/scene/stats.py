"""What a user wants to know about a scene file: counts, bounds, appearance, and its free volume.

Free volume is the room's free space around the take-off point (`scene.free_space`, the space the
evaluation uses, at a coarser voxel): enclosed by the surface, or else bounded by the scan's extent
with its holes closed.
"""

from __future__ import annotations

import numpy as np

from flightrecon.scene.free_space import room_free_space
from flightrecon.scene.levels import scene_levels
from flightrecon.scene.types import Scene


def free_space(scene: Scene, takeoff: np.ndarray, pitch: float = 0.1) -> dict:
    """Volume (m^3) of the room's free space around `takeoff`, whether the surface encloses it, and
    `free_space_error` instead where the take-off point is not free."""
    try:
        free = room_free_space(scene, takeoff, pitch)
    except ValueError as exc:
        return {"free_volume_m3": None, "enclosed": False, "free_space_error": str(exc)}
    return {"free_volume_m3": round(free.volume_m3, 3), "enclosed": free.enclosed}


def _up_axis(scene: Scene) -> dict:
    """How the file was turned z-up: the mode (z, y, auto, vector), the file's up vector, the extra
    rotation and, under auto, the estimate (`scene.gravity.GravityEstimate.to_dict`)."""
    up = scene.meta.get("up_axis") or {}
    default = {"y": [0.0, 1.0, 0.0]}.get(scene.source_up_axis, [0.0, 0.0, 1.0])
    return {"up_axis_mode": up.get("mode", scene.source_up_axis),
            "up_vector": [round(float(x), 5) for x in up.get("up", default)],
            "rotation_deg": [float(x) for x in up.get("rotation_deg", [0.0, 0.0, 0.0])],
            "up_estimate": up.get("estimate")}


def summary(scene: Scene, takeoff: np.ndarray | None = None) -> dict:
    """Counts, bounds (m), size, up axis of the file (and how it was found), appearance, floor and
    ceiling heights (None: no ceiling) and, given the take-off point, the free volume around it."""
    lo, hi = scene.bounds
    out = {
        "name": scene.name,
        "source": str(scene.source) if scene.source else None,
        "vertices": int(len(scene.vertices)),
        "triangles": int(len(scene.faces)),
        "quads": int(len(scene.faces) // 2) if scene.meta.get("quad_faces") else 0,
        "bounds_min": [round(float(x), 4) for x in lo],
        "bounds_max": [round(float(x), 4) for x in hi],
        "size": [round(float(x), 4) for x in hi - lo],
        "file_up_axis": scene.source_up_axis,
        **_up_axis(scene),
        "appearance": scene.appearance,
        "normals": scene.vertex_normals is not None,
        "surface_area_m2": round(float(scene.trimesh.area), 3),
    }
    if scene.appearance == "texture":
        out["texture_size"] = [int(scene.texture.shape[1]), int(scene.texture.shape[0])]
    levels = scene_levels(scene)
    out["floor_z"] = round(levels.floor_z, 4)
    out["ceiling_z"] = None if levels.ceiling_z is None else round(levels.ceiling_z, 4)
    out["levels_from"] = levels.source
    for key in ("kind", "free_box", "spawn"):
        if key in scene.meta:
            out[key] = scene.meta[key]
    if takeoff is not None:
        out.update(free_space(scene, takeoff))
    return out
