"""Load any supported mesh file into a `Scene` (z-up, meters), or fail with one clear SceneError.

Formats: Replica's mesh.ply and any PLY with per-vertex colors (our reader), OBJ + MTL with a UV
texture and GLB/GLTF (trimesh). Options scale units and rotate the file to z-up: its up axis is z,
y, an explicit vector, or "auto" (estimated from the mesh's floor and walls, `scene.gravity`), then
an optional extra rotation. A sidecar
`scene_meta.json` written beside a procedural mesh restores its metadata (free flight region etc.).
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path

import numpy as np

from flightrecon.errors import SceneError
from flightrecon.scene.gravity import AXIS_ROTATIONS, estimate_up, rotation_to_z
from flightrecon.scene.replica_ply import read_ply
from flightrecon.scene.types import Scene

META_FILE = "scene_meta.json"
MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf")
_FRAME_KEYS = ("floor_z", "ceiling_z", "room_box", "free_box", "spawn", "openings")
UP_AXES = ("z", "y", "auto")
MAX_EXTENT_M = 200.0  # a scene larger than this in any direction is not a room read in the right unit
ROOM_HEIGHT_M = (1.8, 8.0)  # the height of a room, to guess a file's unit from
UNIT_GUESSES = (0.001, 0.01, 0.0254)  # millimetres, centimetres, inches

log = logging.getLogger(__name__)

# y-up file -> z-up world: +90 deg about x, so file +y becomes world +z and file +z becomes world -y.
FILE_Z_TOLERANCE_DEG = 10.0  # an uncertain estimate this close to the file's z axis vouches for it
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def load_scene(path: str | os.PathLike, unit_scale: float = 1.0, up_axis: str = "z",
               name: str | None = None, up_vector=None, rotation_deg=None) -> Scene:
    """Read a scene file (or a folder holding mesh.ply, Replica's layout) into the world frame.

    `up_axis`: "z", "y" or "auto" (estimated; an uncertain estimate keeps the file's axes, with a
    warning, when it lies within FILE_Z_TOLERANCE_DEG of the file's z axis, and is a SceneError
    otherwise: neither can then be trusted to put the floor level). `up_vector` (3 numbers, file
    coordinates; None or empty: unused) overrides it.
    `rotation_deg`: an extra rotation about world x, then y, then z (degrees) after the up axis.
    What was applied, and the estimate, are in `scene.meta["up_axis"]`."""
    path = Path(path).expanduser()
    if path.is_dir() and (path / "mesh.ply").is_file():
        path = path / "mesh.ply"
    if not path.exists():
        raise SceneError(f"scene file not found: {path}")
    if not path.is_file():
        raise SceneError(f"scene path is not a file: {path}")
    if up_axis not in UP_AXES:
        raise SceneError(f"scene {path}: scene.up_axis must be 'z', 'y' or 'auto', got {up_axis!r}")
    up_vector = _vector3(path, "scene.up_vector", up_vector)
    rotation_deg = _vector3(path, "scene.rotation_deg", rotation_deg)
    if up_vector is not None and not np.linalg.norm(up_vector) > 0:
        raise SceneError(f"scene {path}: scene.up_vector is a zero-length vector {up_vector.tolist()}; "
                         "give the file's up direction, e.g. [0, 1, 0], or [] to not use it")
    if not (np.isfinite(unit_scale) and unit_scale > 0):
        raise SceneError(f"scene {path}: unit scale must be a positive number, got {unit_scale!r}")
    suffix = path.suffix.lower()
    if suffix == ".ply":
        d = read_ply(path)
    elif suffix in (".obj", ".glb", ".gltf"):
        d = _read_trimesh(path)
    else:
        raise SceneError(f"scene file {path}: unsupported format '{suffix}' (use {', '.join(MESH_SUFFIXES)})")
    meta = {"quad_faces": bool(d.pop("quad_faces", False))}
    meta.update(_read_sidecar(path))
    default_name = path.parent.name if path.name == "mesh.ply" else path.stem
    scene = Scene(name=name or meta.get("name") or default_name, vertices=d["vertices"], faces=d["faces"], vertex_colors=d.get("vertex_colors"),
                  face_colors=d.get("face_colors"), uv=d.get("uv"), texture=d.get("texture"),
                  vertex_normals=d.get("vertex_normals"), source=path, source_up_axis=up_axis, meta=meta)
    validate(scene, path)
    _check_size(scene, path, unit_scale)
    R = _orientation(scene, path, unit_scale, up_axis, up_vector, rotation_deg)
    _to_world(scene, unit_scale, R)
    return scene


def _check_size(scene: Scene, path: Path, unit_scale: float) -> None:
    """Refuse a scene far larger than any room (almost always a file in millimetres or centimetres read
    as metres), naming the scale that gives it a room's height, before anything sized by it is built."""
    extent = np.ptp(scene.vertices, axis=0) * unit_scale
    if float(extent.max()) <= MAX_EXTENT_M:
        return
    side = float(extent.min())  # a room's smallest side is about its height, whichever way the file is up
    fits = [scale for scale in UNIT_GUESSES if ROOM_HEIGHT_M[0] <= side * scale <= ROOM_HEIGHT_M[1]]
    guess = (f"with scene.unit_scale = {unit_scale * fits[0]:g} its smallest side is {side * fits[0]:.2f} m, a room's "
             "height" if fits else "set scene.unit_scale to the file's unit in metres")
    raise SceneError(f"scene {path} spans {float(extent.max()):.0f} m ({' x '.join(f'{x:.0f}' for x in extent)} m, file axes, at "
                     f"scene.unit_scale = {unit_scale:g}), more than any room: its coordinates are likely in "
                     f"another unit; {guess}")


def validate(scene: Scene, path: Path | str) -> None:
    """Reject empty meshes, NaN/inf vertices, out-of-range faces and mismatched appearance arrays."""
    v, f = scene.vertices, scene.faces
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise SceneError(f"scene file {path} has no vertices")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise SceneError(f"scene file {path} has no faces")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise SceneError(f"scene file {path} has {int(bad.sum())} vertices with NaN or infinite "
                         f"coordinates (first: vertex {int(np.argmax(bad))})")
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"scene file {path} has faces that index missing vertices "
                         f"(indices {int(f.min())}..{int(f.max())}, {len(v)} vertices)")
    for attr, n in (("vertex_colors", len(v)), ("uv", len(v)), ("vertex_normals", len(v)), ("face_colors", len(f))):
        a = getattr(scene, attr)
        if a is not None and len(a) != n:
            raise SceneError(f"scene file {path}: {attr} has {len(a)} entries for {n} elements")
    extent = np.ptp(v, axis=0)
    if not np.any(extent > 0):
        raise SceneError(f"scene file {path} is degenerate (all vertices at one point)")


def _vector3(path: Path, key: str, value) -> np.ndarray | None:
    """None or an empty list -> None; otherwise exactly 3 finite numbers, else a SceneError naming `key`."""
    if value is None or (isinstance(value, (list, tuple)) and len(value) == 0):
        return None
    try:
        ok = len(value) == 3 and all(not isinstance(x, bool) for x in value)
        arr = np.asarray(value, np.float64) if ok else None
    except (TypeError, ValueError):
        ok = False
    if not ok or arr.shape != (3,) or not np.isfinite(arr).all():
        raise SceneError(f"scene {path}: {key} must be 3 finite numbers (x, y, z), got {value!r}")
    return arr


def _rotation_xyz(deg: np.ndarray) -> np.ndarray:
    """Rotation about world x, then y, then z by `deg` (degrees): Rz @ Ry @ Rx."""
    ax, ay, az = (math.radians(float(d)) for d in deg)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _axis_label(up: np.ndarray) -> str:
    for name, R in AXIS_ROTATIONS.items():
        if np.array_equal(R @ up, [0.0, 0.0, 1.0]) and np.count_nonzero(up) == 1:
            return name
    return "(" + ", ".join(f"{x:.3f}" for x in up) + ")"


def _orientation(scene: Scene, path: Path, unit_scale: float, up_axis: str, up_vector: np.ndarray | None,
                 rotation_deg: np.ndarray | None) -> np.ndarray:
    """The file -> world rotation; records what was applied in scene.source_up_axis and meta["up_axis"]."""
    estimate = None
    if up_vector is not None:
        mode, up = "vector", up_vector / np.linalg.norm(up_vector)
        R = rotation_to_z(up)
    elif up_axis == "auto":
        estimate = estimate_up(scene.vertices, scene.faces, unit_scale)
        mode = "auto"
        if estimate.confident:
            up, R = estimate.up, estimate.rotation
        else:
            up, R = np.array([0.0, 0.0, 1.0]), np.eye(3)
            e = estimate.up
            off = math.degrees(math.acos(min(1.0, abs(float(e[2])))))
            if off > FILE_Z_TOLERANCE_DEG:  # never fly a scan tilted: neither the estimate nor the file's z is trusted
                raise SceneError(
                    f"scene {path}: cannot tell which way is up. scene.up_axis = 'auto' estimates up = "
                    f"({e[0]:.3f}, {e[1]:.3f}, {e[2]:.3f}) in the file's coordinates but is uncertain "
                    f"({estimate.reason}), and the file's z axis is {off:.0f} deg from it, so its floor would not be "
                    f"level either. Set scene.up_vector = [{e[0]:.3f}, {e[1]:.3f}, {e[2]:.3f}] to use the estimate, "
                    "or scene.up_axis = \"y\" or \"z\" if the file is stored so (`flightrecon scene info FILE "
                    "--up-vector X Y Z` shows the floor and workspace it gives)")
            log.warning("scene %s: scene.up_axis = 'auto' is uncertain (%s; estimate (%.3f, %.3f, %.3f)); keeping "
                        "the file's z axis as up, which it agrees with: set scene.up_axis or scene.up_vector",
                        path, estimate.reason, *e)
    else:
        mode = up_axis
        up = np.array([0.0, 1.0, 0.0]) if up_axis == "y" else np.array([0.0, 0.0, 1.0])
        R = _Y_UP_TO_Z_UP if up_axis == "y" else np.eye(3)
    if rotation_deg is not None and np.any(rotation_deg != 0):
        R = _rotation_xyz(rotation_deg) @ R
    scene.source_up_axis = _axis_label(up)
    scene.meta["up_axis"] = {
        "mode": mode, "up": [float(x) for x in up],
        "rotation_deg": [float(x) for x in rotation_deg] if rotation_deg is not None else [0.0, 0.0, 0.0],
        "rotation": [[float(x) for x in row] for row in R],
        "estimate": estimate.to_dict() if estimate is not None else None}
    return R


def _to_world(scene: Scene, unit_scale: float, R: np.ndarray) -> None:
    scene.vertices = (scene.vertices @ R.T) * unit_scale
    if scene.vertex_normals is not None:
        scene.vertex_normals = scene.vertex_normals @ R.T
    rotated = not np.array_equal(R, np.eye(3))
    if rotated or unit_scale != 1.0:
        dropped = [key for key in _FRAME_KEYS if scene.meta.pop(key, None) is not None]
        if dropped and rotated:  # sidecar values were written in the file's own frame
            log.warning("scene %s: dropped the metadata %s written in the file's frame, which is rotated on "
                        "loading; floor and ceiling come from the geometry", scene.source, ", ".join(dropped))


def _read_trimesh(path: Path) -> dict:
    """OBJ/GLB/GLTF through trimesh: geometry, and UV texture or colors if present."""
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh and its parsers raise many types on malformed input
        raise SceneError(f"cannot read scene file {path}: {type(exc).__name__}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SceneError(f"scene file {path} holds no triangle mesh")
    out: dict = {"vertices": np.asarray(mesh.vertices, np.float64), "faces": np.asarray(mesh.faces, np.int64)}
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        image = getattr(visual.material, "image", None) or getattr(visual.material, "baseColorTexture", None)
        if image is not None:
            out["uv"] = np.asarray(visual.uv, np.float64)
            out["texture"] = np.asarray(image.convert("RGB"), np.uint8)
        else:
            color = getattr(visual.material, "main_color", None)
            if color is not None:
                out["face_colors"] = np.tile(np.asarray(color[:3], np.uint8), (len(mesh.faces), 1))
    elif isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind is not None:
        if visual.kind == "vertex":
            out["vertex_colors"] = np.asarray(visual.vertex_colors[:, :3], np.uint8)
        else:
            out["face_colors"] = np.asarray(visual.face_colors[:, :3], np.uint8)
    return out


def _read_sidecar(path: Path) -> dict:
    """Metadata of a procedural scene written beside its mesh; ignored if it names another mesh."""
    side = path.parent / META_FILE
    if not side.is_file():
        return {}
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SceneError(f"scene metadata {side} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("mesh") != path.name:
        return {}
    return meta
