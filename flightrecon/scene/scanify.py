"""Scan-like test scenes: a procedural room as a real reconstruction of it looks.

Real scans (Replica, ScanNet, Matterport/HM3D, ICL-NUIM, BundleFusion/KinectFusion) are fused from
a hand-held RGB-D recording, so their surfaces are lumpy, what the sensor never saw is a hole, the
ceiling is partial or missing, walls end where the operator stopped pointing, and they are stored in
whatever frame their pipeline chose: the first camera's (a tilted room, up along no axis), y-up,
-y-up or z-up, in meters or millimeters. Our procedural rooms are none of that, so nothing tested the
messy cases. Here a scene is scanned the way a person would (`scene.handheld`), fused with Open3D's
TSDF (`evaluation.tsdf`), cropped and holed as asked, and stored in the asked frame and units.

A procedural scene knows its truth, and each scan carries it in a sidecar `<mesh file>.truth.json`
(`truth_path`): the up vector and the floor height in file coordinates and units, the transform
from the procedural world, the take-off point, the options and the kinds of mess they make. The
loader never reads it (it reads only `scene_meta.json`), so a scan must be understood from its
geometry, as a real one is. The same (scene, seed, options) always give the same bytes: Open3D's
mesh comes in an order that depends on its threads, so vertices and faces are put in a canonical one.
"""

from __future__ import annotations

import json
import math
import os
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from flightrecon.config import SimConfig
from flightrecon.errors import SceneError
from flightrecon.evaluation.tsdf import fuse_depth_maps
from flightrecon.fileio import write_json
from flightrecon.geometry import invert_pose, rot_z
from flightrecon.open3d_import import open3d_module
from flightrecon.planning.poses import start_position
from flightrecon.scene import patterns
from flightrecon.scene.builder import QuadMeshBuilder
from flightrecon.scene.gravity import AXIS_ROTATIONS
from flightrecon.scene.handheld import RaycastCamera, Sensor, handheld_walk, sensor_depth
from flightrecon.scene.levels import scene_levels
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import quads_to_triangles, write_replica_ply
from flightrecon.scene.texture_atlas import per_triangle_atlas, write_textured_obj
from flightrecon.scene.types import Scene

CONVENTIONS = ("camera", "y-up", "-y-up", "z-up")
UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0}  # file units per meter
CEILINGS = ("full", "partial", "none")
APPEARANCES = {".ply": "colors", ".obj": "texture"}  # mesh file suffix -> how it stores colour
TRUTH_FORMAT = "flightrecon.scan_truth"
TRUTH_VERSION = 1
CLEARANCE = 0.3  # m: hand-held poses closer than this to a surface are skipped (the person cannot stand there)
CEILING_GAP = 0.15  # m: with ceiling "none", the crop this far below the ceiling
RAGGED = 0.05  # m: amplitude of the crop height's variation, so a cut edge is not a straight line
HOLE_RADIUS = (0.15, 0.4)  # m
_STREAMS = {"walk": 1, "sensor": 2, "furniture": 3, "holes": 4, "crop": 5}


@dataclass(frozen=True)
class ScanOptions:
    """What the scan looks like and how it is stored (lengths in meters)."""

    convention: str = "z-up"  # camera (the first camera's OpenCV frame), y-up, -y-up, z-up
    units: str = "m"  # m, cm, mm
    ceiling: str = "full"  # full: the operator looks up too; partial: hardly; none: cropped off
    wall_top: float | None = None  # crop everything above this height over the floor (walls end low)
    holes: int = 0  # extra holes cut in the fused surface
    furniture: bool = False  # a box standing where the default take-off point is
    heading_deg: float = 0.0  # turn about up before storing (axis conventions)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # shift before storing (axis conventions)
    frames: int = 90  # hand-held poses along the walk
    voxel: float = 0.03  # TSDF voxel
    max_faces: int | None = 150_000  # decimate to this many triangles (quadric error), as scans ship; None: keep all
    sensor: Sensor = field(default_factory=Sensor)

    def __post_init__(self) -> None:
        def bad(what: str) -> SceneError:
            return SceneError(f"scan option {what}")
        if self.convention not in CONVENTIONS:
            raise bad(f"convention={self.convention!r}: choose one of {', '.join(CONVENTIONS)}")
        if self.units not in UNITS:
            raise bad(f"units={self.units!r}: choose one of {', '.join(UNITS)}")
        if self.ceiling not in CEILINGS:
            raise bad(f"ceiling={self.ceiling!r}: choose one of {', '.join(CEILINGS)}")
        if self.wall_top is not None and not 0.5 <= self.wall_top <= 5.0:
            raise bad(f"wall_top={self.wall_top}: give a height over the floor in meters (0.5 to 5), e.g. 1.8")
        if self.holes < 0 or self.frames < 1 or not self.voxel > 0 or (self.max_faces is not None
                                                                        and self.max_faces < 1000):
            raise bad(f"holes={self.holes}, frames={self.frames}, voxel={self.voxel}, max_faces={self.max_faces}: "
                      "holes must be >= 0, frames >= 1, voxel > 0 and max_faces >= 1000 (or None)")
        if len(self.offset) != 3:
            raise bad(f"offset={self.offset!r}: give 3 numbers (x, y, z)")
        if self.convention == "camera" and (self.heading_deg or any(self.offset)):
            raise bad("heading_deg and offset place an axis-aligned file (y-up, -y-up, z-up); the camera "
                      "convention is placed by its first camera: drop them or choose another convention")

    def kinds(self) -> frozenset[str]:
        """Tags of the mess this scan has, for selecting scans: the convention, the units, one of
        ceiling / partial-ceiling / no-ceiling, low-walls, holes, furniture, turned (walls along no
        file axis)."""
        no_ceiling = self.ceiling == "none" or self.wall_top is not None
        tags = {self.convention, self.units,
                "no-ceiling" if no_ceiling else ("partial-ceiling" if self.ceiling == "partial" else "ceiling")}
        if self.wall_top is not None:
            tags.add("low-walls")
        if self.holes:
            tags.add("holes")
        if self.furniture:
            tags.add("furniture")
        if self.convention == "camera" or self.heading_deg % 90:
            tags.add("turned")
        return frozenset(tags)


@dataclass
class Scan:
    """A fused scan in its file's frame and units, and the truth about it (the sidecar's content)."""

    vertices: np.ndarray  # (V, 3) float64, file coordinates
    faces: np.ndarray  # (F, 3) int64
    vertex_colors: np.ndarray  # (V, 3) uint8
    truth: dict


def scan_procedural(name: str, seed: int = 0, options: ScanOptions | None = None) -> Scan:
    """Scan the procedural scene `name` (seed `seed`, which also drives the scan's own randomness)."""
    return scanify(make_scene(name, seed), options or ScanOptions(), seed)


def scan_subject(scene: Scene, options: ScanOptions, seed: int = 0) -> Scene:
    """The z-up scene that is scanned: `scene`, plus the furniture at the take-off spot if asked.
    It is the ground truth a scan's surface is compared with."""
    if not options.furniture:
        return scene
    rng = _rng("furniture", scene.name, seed)
    foot = start_position(scene, 0.0)
    size = [rng.uniform(0.5, 0.7), rng.uniform(0.5, 0.7), rng.uniform(0.9, 1.3)]
    b = QuadMeshBuilder()
    b.box(foot + [0.0, 0.0, size[2] / 2], size, patterns.wood(rng), 0.05, R=rot_z(rng.uniform(0, math.pi / 2)),
          hidden=("-z",))
    v, c, _, q = b.build()
    meta = dict(scene.meta, furniture={"foot_world": foot.tolist(), "size_m": [float(x) for x in size]})
    return Scene(scene.name, np.vstack([scene.vertices, v]),
                 np.vstack([scene.faces, quads_to_triangles(q) + len(scene.vertices)]),
                 vertex_colors=np.vstack([_colors(scene), c]), meta=meta)


def scanify(scene: Scene, options: ScanOptions | None = None, seed: int = 0) -> Scan:
    """A hand-held scan of the z-up `scene` (meters) as `options` ask; deterministic in (scene, seed, options)."""
    options = options or ScanOptions()
    subject = scan_subject(scene, options, seed)
    camera = RaycastCamera(subject, _colors(subject), options.sensor)
    poses = _walk(camera, subject, options, seed)
    vertices, faces, colors = _canonical(*_fuse(camera, poses, options, _rng("sensor", scene.name, seed)))
    top = _crop_height(scene, options)
    keep = np.ones(len(faces), bool)
    if top is not None:
        keep &= _below(vertices, faces, top, _rng("crop", scene.name, seed))
    if options.holes:
        keep &= ~_holes(vertices, faces, keep, options.holes, _rng("holes", scene.name, seed))
    if not keep.any():
        raise SceneError(f"the scan of {scene.name} kept no surface: raise wall_top, cut fewer holes "
                         "or walk more frames")
    vertices, faces, colors = _canonical(vertices, faces[keep], colors)
    if options.max_faces is not None and len(faces) > options.max_faces:
        vertices, faces, colors = _canonical(*_decimate(vertices, faces, colors, options.max_faces))
    R, t = _placement(options, poses[0])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = UNITS[options.units] * R, UNITS[options.units] * t
    truth = _truth(scene, options, seed, T, top, len(poses))
    if options.furniture:
        truth["furniture"] = subject.meta["furniture"]
    return Scan(vertices @ T[:3, :3].T + T[:3, 3], faces, colors, truth)


def _truth(scene: Scene, options: ScanOptions, seed: int, T: np.ndarray, top: float | None, frames: int) -> dict:
    """The sidecar's content: heights are along the file's up vector, in file units."""
    up = T[:3, 2] / np.linalg.norm(T[:3, 2])
    spawn = start_position(scene, 0.0)
    to_file = lambda z: T[:3, :3] @ (spawn + [0.0, 0.0, z - spawn[2]]) + T[:3, 3]  # noqa: E731  (world z over spawn)
    height = lambda z: None if z is None else float(up @ to_file(z))  # noqa: E731
    levels = scene_levels(scene)
    return {
        "format": TRUTH_FORMAT, "version": TRUTH_VERSION, "scene": scene.name, "seed": int(seed),
        "convention": options.convention, "units": options.units, "meters_per_unit": 1.0 / UNITS[options.units],
        "up": [float(x) for x in up], "floor": height(levels.floor_z), "ceiling": height(levels.ceiling_z),
        "top": height(top),
        "takeoff_point": [float(x) for x in to_file(spawn[2] + SimConfig().takeoff_height)],
        "file_from_world": T.tolist(), "frames": int(frames),
        "kinds": sorted(options.kinds()), "options": asdict(options),
    }


def write_scan(scan: Scan, path: str | os.PathLike) -> list[Path]:
    """Write the scan as PLY with vertex colours (.ply) or OBJ + MTL + PNG atlas (.obj), and its
    truth sidecar; returns the written paths, the mesh first."""
    path = Path(path)
    appearance = APPEARANCES.get(path.suffix.lower())
    if appearance is None:
        raise SceneError(f"scan file {path}: use a .ply (vertex colours) or .obj (texture atlas) name")
    if appearance == "colors":
        written = [write_replica_ply(Scene(path.stem, scan.vertices, scan.faces, vertex_colors=scan.vertex_colors),
                                     path)]
    else:
        written = write_textured_obj(path, *per_triangle_atlas(scan.vertices, scan.faces, scan.vertex_colors))
    truth = dict(scan.truth, mesh=path.name, appearance=appearance, kinds=sorted({*scan.truth["kinds"], appearance}))
    write_json(truth_path(path), truth)
    return written + [truth_path(path)]


def truth_path(mesh: str | os.PathLike) -> Path:
    """The truth sidecar of a scan file (not `scene_meta.json`, which the loader would read)."""
    mesh = Path(mesh)
    return mesh.with_name(mesh.name + ".truth.json")


def read_truth(mesh: str | os.PathLike) -> dict:
    """The truth sidecar of a scan file written by `write_scan`."""
    side = truth_path(mesh)
    try:
        truth = json.loads(side.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"scan truth {side} not found: write the scan with `flightrecon scene scanify`") from None
    except ValueError as exc:
        raise SceneError(f"scan truth {side} is not valid JSON: {exc}; write the scan again") from None
    if truth.get("format") != TRUTH_FORMAT:
        raise SceneError(f"{side} is not a scan truth sidecar (format {truth.get('format')!r})")
    return truth


def _colors(scene: Scene) -> np.ndarray:
    """The scene's vertex colours, or a light grey where it has none."""
    if scene.vertex_colors is not None:
        return scene.vertex_colors
    return np.full((len(scene.vertices), 3), 180, np.uint8)


def _rng(stream: str, name: str, seed: int) -> np.random.Generator:
    """One random stream per purpose, so a scan stored in another frame or units has the same surface."""
    return np.random.default_rng([_STREAMS[stream], zlib.crc32(name.encode()), int(seed)])


def _walk(camera: RaycastCamera, subject: Scene, options: ScanOptions, seed: int) -> np.ndarray:
    """The hand-held poses that keep CLEARANCE from every surface."""
    lo, hi = np.asarray(subject.meta.get("room_box", subject.bounds), float)
    poses = handheld_walk(start_position(subject, 0.0), (hi - lo) / 2, options.frames,
                          _rng("walk", subject.name, seed), look_up=options.ceiling == "full")
    clear = camera.clearance(poses[:, :3, 3]) >= CLEARANCE
    if not clear.any():
        raise SceneError(f"no hand-held pose in {subject.name} keeps {CLEARANCE} m from its surfaces: "
                         "the scene needs free space around its spawn (floor center) at 1.2-1.7 m")
    return poses[clear]


def _fuse(camera: RaycastCamera, poses: np.ndarray, options: ScanOptions, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, faces, uint8 colours) fused from the sensor's noisy depth and colour at `poses`."""
    sensor = options.sensor
    depths, images = [], []
    for T in poses:
        depth, rgb, cos = camera.render(T)
        depths.append(sensor_depth(depth, cos, sensor, rng))
        images.append(np.clip(rgb * rng.normal(1.0, 0.03), 0.0, 1.0))  # auto-exposure varies per frame
    mesh = fuse_depth_maps(depths, poses, sensor.K, voxel=options.voxel, truncation=4 * options.voxel,
                           max_depth=sensor.max_depth, colors=images)
    rgb = np.clip(np.round(mesh.vertex_colors * 255.0), 0, 255).astype(np.uint8)
    return mesh.vertices, mesh.faces, rgb


def _crop_height(scene: Scene, options: ScanOptions) -> float | None:
    """World z above which the scan is cut off, or None."""
    levels = scene_levels(scene)
    tops = []
    if options.ceiling == "none" and levels.ceiling_z is not None:
        tops.append(levels.ceiling_z - CEILING_GAP)
    if options.wall_top is not None:
        tops.append(levels.floor_z + options.wall_top)
    return min(tops) if tops else None


def _below(vertices: np.ndarray, faces: np.ndarray, top: float, rng: np.random.Generator) -> np.ndarray:
    """Faces wholly below `top`, give or take RAGGED along a smooth noise, as a scan's cut-off edge."""
    tri = vertices[faces]
    salt = int(rng.integers(0, 1 << 20))
    ragged = top + RAGGED * (2 * patterns.value_noise(tri[:, :, 0].mean(1), tri[:, :, 1].mean(1), 1.0, salt) - 1)
    return tri[:, :, 2].max(1) <= ragged


def _holes(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray, count: int, rng: np.random.Generator
           ) -> np.ndarray:
    """Faces within a random radius of `count` random points of the kept surface (area-weighted)."""
    centroid = vertices[faces].mean(1)
    area = np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                   vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1) * keep
    cut = np.zeros(len(faces), bool)
    if area.sum() <= 0:
        return cut
    for k in rng.choice(len(faces), size=count, p=area / area.sum()):
        cut |= np.linalg.norm(centroid - centroid[k], axis=1) < rng.uniform(*HOLE_RADIUS)
    return cut


def _canonical(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Only the referenced vertices, sorted by position, and faces sorted, each starting at its
    smallest index (winding kept): the same surface always gives the same arrays."""
    used = np.unique(faces)
    order = used[np.lexsort(vertices[used].T[::-1])]
    new = np.empty(len(vertices), np.int64)
    new[order] = np.arange(len(order))
    f = new[faces]
    f = np.take_along_axis(f, (np.argmin(f, 1)[:, None] + np.arange(3)) % 3, 1)
    f = f[np.lexsort(f.T[::-1])]
    return vertices[order], f, colors[order]


def _decimate(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, target: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Open3D's quadric error decimation to `target` triangles, colours carried along."""
    o3d = open3d_module()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces))
    mesh.vertex_colors = o3d.utility.Vector3dVector(colors / 255.0)
    mesh = mesh.simplify_quadric_decimation(int(target))
    rgb = np.clip(np.round(np.asarray(mesh.vertex_colors) * 255.0), 0, 255).astype(np.uint8)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64), rgb


def _placement(options: ScanOptions, first_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t): file = units * (R @ world + t)."""
    if options.convention == "camera":
        T_cw = invert_pose(first_pose)
        return T_cw[:3, :3], T_cw[:3, 3]
    R = AXIS_ROTATIONS[options.convention.removesuffix("-up")].T @ rot_z(math.radians(options.heading_deg))
    return R, R @ np.asarray(options.offset, float)

