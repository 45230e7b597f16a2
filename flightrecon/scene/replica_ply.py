"""Replica's mesh.ply: binary little-endian PLY, quad faces, per-vertex position, normal and RGB.

The writer emits exactly Replica's layout (so the procedural scenes exercise the real-data loader);
the reader accepts any PLY with polygon faces and optional vertex colors and normals (ascii or
binary, quads or triangles, as scanned rooms ship) and splits polygons into triangles.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from flightrecon.errors import SceneError
from flightrecon.fileio import atomic_path
from flightrecon.scene.types import Scene

_VERTEX_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                          ("nz", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def quads_to_triangles(quads: np.ndarray) -> np.ndarray:
    """Split quads (a, b, c, d) into triangles (a, b, c), (a, c, d), kept in consecutive pairs."""
    quads = np.asarray(quads, np.int64)
    return np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)


def triangles_to_quads(faces: np.ndarray) -> np.ndarray:
    """Inverse of `quads_to_triangles` for a scene whose faces are consecutive quad halves."""
    pairs = np.asarray(faces).reshape(-1, 2, 3)
    return np.concatenate([pairs[:, 0, :], pairs[:, 1, 2:3]], axis=1)


def write_replica_ply(scene: Scene, path: str | os.PathLike) -> Path:
    """Write `scene` as Replica's binary mesh.ply (quads when the scene came from quads), atomically."""
    path = Path(path)
    n = len(scene.vertices)
    vert = np.zeros(n, _VERTEX_DTYPE)
    for k, name in enumerate("xyz"):
        vert[name] = scene.vertices[:, k]
    normals = scene.vertex_normals
    if normals is None:
        normals = scene.trimesh.vertex_normals
    for k, name in enumerate(("nx", "ny", "nz")):
        vert[name] = normals[:, k]
    colors = scene.vertex_colors if scene.vertex_colors is not None else np.full((n, 3), 200, np.uint8)
    for k, name in enumerate(("red", "green", "blue")):
        vert[name] = colors[:, k]
    polys = triangles_to_quads(scene.faces) if scene.meta.get("quad_faces") else np.asarray(scene.faces)
    face = np.zeros(len(polys), np.dtype([("n", "u1"), ("v", "<i4", (polys.shape[1],))]))
    face["n"] = polys.shape[1]
    face["v"] = polys
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {n}\n"
              + "".join(f"property float {p}\n" for p in ("x", "y", "z", "nx", "ny", "nz"))
              + "property uchar red\nproperty uchar green\nproperty uchar blue\n"
              f"element face {len(polys)}\nproperty list uchar int vertex_indices\nend_header\n")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())
    return path


def read_ply(path: str | os.PathLike) -> dict:
    """Vertices, triangle faces, optional colors and normals of a PLY file; SceneError if unreadable.

    Returns a dict with keys vertices (V,3) float64, faces (F,3) int64, vertex_colors (V,3) uint8
    or None, vertex_normals or None, quad_faces (True when every polygon was a quad)."""
    import plyfile

    path = Path(path)
    fast = _read_uniform_binary(path)
    if fast is not None:
        return fast
    try:
        ply = plyfile.PlyData.read(str(path))
        vertex = ply["vertex"].data
        names = vertex.dtype.names
        vertices = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
        face_el = ply["face"] if "face" in [e.name for e in ply.elements] else None
        polys = None if face_el is None else face_el.data[face_el.data.dtype.names[0]]
    except SceneError:
        raise
    except Exception as exc:  # plyfile raises many types for truncated or malformed input
        raise SceneError(f"cannot read PLY file {path}: {type(exc).__name__}: {exc}") from None
    if polys is None or len(polys) == 0:
        raise SceneError(f"PLY file {path} has no faces (a mesh is needed, not a point cloud)")
    faces, quad = _triangulate(polys, path)
    colors = None
    if all(c in names for c in ("red", "green", "blue")):
        colors = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)
        if colors.dtype != np.uint8:  # float colors in [0, 1]
            colors = np.clip(np.round(colors.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    normals = None
    if all(c in names for c in ("nx", "ny", "nz")):
        normals = np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1).astype(np.float64)
    return {"vertices": vertices, "faces": faces, "vertex_colors": colors, "vertex_normals": normals,
            "quad_faces": quad}


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
              "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
              "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}


def _read_uniform_binary(path: Path) -> dict | None:
    """Fast path for the common layout (Replica's): little-endian binary, scalar vertex properties,
    then faces that all have the same vertex count. None when the file is laid out otherwise."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
            end = head.find(b"end_header\n")
            if not head.startswith(b"ply") or end < 0:
                return None
            lines = head[:end].decode("ascii", "replace").splitlines()
            fh.seek(end + len(b"end_header\n"))
            body = fh.read()
    except OSError as exc:
        raise SceneError(f"cannot read PLY file {path}: {exc}") from None
    if "format binary_little_endian 1.0" not in lines:
        return None
    elements: list[list] = []
    for line in lines:
        w = line.split()
        if w[:1] == ["element"] and len(w) == 3:
            elements.append([w[1], int(w[2]), []])
        elif w[:1] == ["property"] and elements:
            elements[-1][2].append(w[1:])
    if [e[0] for e in elements] != ["vertex", "face"]:
        return None
    (_, nv, vprops), (_, nf, fprops) = elements
    if any(len(p) != 2 or p[0] not in _PLY_TYPES for p in vprops) or len(fprops) != 1 \
            or fprops[0][0] != "list" or fprops[0][1] not in ("uchar", "uint8") \
            or fprops[0][2] not in ("int", "int32", "uint", "uint32"):
        return None
    vdtype = np.dtype([(p[1], _PLY_TYPES[p[0]]) for p in vprops])
    vbytes = nv * vdtype.itemsize
    if nf == 0 or len(body) <= vbytes:
        return None  # let the general reader report what is missing
    k = body[vbytes]
    fdtype = np.dtype([("n", "u1"), ("v", _PLY_TYPES[fprops[0][2]], (k,))])
    if len(body) != vbytes + nf * fdtype.itemsize:
        return None
    vertex = np.frombuffer(body, vdtype, nv)
    face = np.frombuffer(body, fdtype, nf, offset=vbytes)
    if k < 3 or np.any(face["n"] != k) or not all(c in vdtype.names for c in "xyz"):
        return None
    faces, quad = _triangulate(face["v"].astype(np.int64), path)
    names = vdtype.names
    colors = None
    if all(c in names for c in ("red", "green", "blue")) and vertex.dtype["red"] == np.uint8:
        colors = np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1)
    elif any(c in names for c in ("red", "green", "blue")):
        return None  # float or partial colors: the general reader converts them
    normals = None
    if all(c in names for c in ("nx", "ny", "nz")):
        normals = np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1).astype(np.float64)
    return {"vertices": np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64),
            "faces": faces, "vertex_colors": colors, "vertex_normals": normals, "quad_faces": quad}


def _triangulate(polys, path: Path) -> tuple[np.ndarray, bool]:
    """Fan-split each polygon; fast path when all polygons have the same size."""
    if isinstance(polys, np.ndarray) and polys.dtype != object and polys.ndim == 2:
        arr = polys
    else:
        lengths = np.fromiter((len(p) for p in polys), np.int64, len(polys))
        if np.all(lengths == lengths[0]):
            arr = np.stack(list(polys))
        else:
            tris = [np.asarray([p[0], p[k], p[k + 1]]) for p in polys for k in range(1, len(p) - 1)]
            if not tris:
                raise SceneError(f"PLY file {path} has no polygon with 3 or more vertices")
            return np.asarray(tris, np.int64), False
    arr = np.asarray(arr, np.int64)
    if arr.shape[1] < 3:
        raise SceneError(f"PLY file {path} has faces with fewer than 3 vertices")
    if arr.shape[1] == 4:
        return quads_to_triangles(arr), True
    k = np.arange(1, arr.shape[1] - 1)
    tris = np.stack([np.repeat(arr[:, :1], len(k), 1), arr[:, k], arr[:, k + 1]], axis=2)
    return tris.reshape(-1, 3), False
