"""Bake a scene's per-vertex (or per-face) colors into a texture atlas MuJoCo can draw.

MuJoCo meshes have no vertex colors. Each quad (or lone triangle) gets its own 4 x 4 texel patch,
4-aligned, holding the face's barycentric color field (each triangle's affine field extended
over its side of the patch). The face spans the inner 2 x 2 texels (corners one texel in from the
patch border), so bilinear sampling at mip levels 0 and 1 reads only that face's patch: unrelated
colors never bleed in. The renderer stops the mip chain at `MAX_MIP_LEVEL`, where level 1 gives
exactly the bilinear blend of the face's corner colors. Patches are ordered along a 3D Morton
curve of their centroids and placed along a 2D Morton curve, so atlas neighbours are mostly scene
neighbours. A UV-textured scene keeps its own texture and full mip chain.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from flightrecon.scene.types import Scene

PATCH = 4  # texels per patch side
INSET = 1.0  # texels between the patch border and the face's corners
MAX_MIP_LEVEL = 1  # mip levels 0..1 sample only inside a patch (level-1 texel centers = face corners)


@dataclass
class TextureAtlas:
    """An RGB image plus per-face-corner texture coordinates (MuJoCo's: texel row = v * height)."""

    image: np.ndarray  # (H, W, 3) uint8
    texcoord: np.ndarray  # (T, 2) float32
    face_texcoord: np.ndarray  # (F, 3) int32 indices into texcoord, one per face corner
    max_mip_level: int = 1000  # the renderer must not use coarser mip levels than this


def scene_hash(scene: Scene) -> str:
    """Content hash of geometry and appearance: the key of every baked asset."""
    h = hashlib.sha1()
    for a in (scene.vertices, scene.faces, scene.vertex_colors, scene.face_colors, scene.uv, scene.texture):
        if a is None:
            h.update(b"-")
        else:
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype.str, a.shape)).encode())
            h.update(a.data)
    h.update(b"quads" if scene.meta.get("quad_faces") else b"tris")
    return h.hexdigest()


def bake_atlas(scene: Scene) -> TextureAtlas:
    """The atlas for `scene`'s appearance (see the module docstring)."""
    if scene.appearance == "texture":
        uv = np.asarray(scene.uv, np.float32).copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # files put v = 0 at the image bottom, MuJoCo at row 0
        return TextureAtlas(np.ascontiguousarray(scene.texture[..., :3], dtype=np.uint8), uv,
                            np.asarray(scene.faces, np.int32))
    faces = np.asarray(scene.faces, np.int64)
    if scene.vertex_colors is not None:
        corner_colors = scene.vertex_colors.astype(np.float32)[faces]  # (F, 3 corners, 3)
    elif scene.face_colors is not None:
        corner_colors = np.repeat(scene.face_colors.astype(np.float32)[:, None], 3, axis=1)
    else:
        corner_colors = np.full((len(faces), 3, 3), 180.0, np.float32)
    quads = bool(scene.meta.get("quad_faces")) and len(faces) % 2 == 0
    if quads:
        pairs = faces.reshape(-1, 2, 3)
        if not (np.array_equal(pairs[:, 0, 0], pairs[:, 1, 0]) and np.array_equal(pairs[:, 0, 2], pairs[:, 1, 1])):
            quads = False  # not consecutive halves (a, b, c), (a, c, d) after all
    s, t = _patch_coords()
    if quads:
        c = corner_colors.reshape(-1, 2, 3, 3)
        c0, c1, c2, c3 = c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 2]
        lower = (s >= t)[None, :, :, None]  # triangle (c0, c1, c2) covers s >= t
        tex_a = c0[:, None, None] * (1 - s)[None, ..., None] + c1[:, None, None] * (s - t)[None, ..., None] \
            + c2[:, None, None] * t[None, ..., None]
        tex_b = c0[:, None, None] * (1 - t)[None, ..., None] + c2[:, None, None] * s[None, ..., None] \
            + c3[:, None, None] * (t - s)[None, ..., None]
        texels = np.where(lower, tex_a, tex_b)
        centroids = scene.vertices[faces.reshape(-1, 6)].mean(axis=1)
        corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
        corner_idx = np.array([[0, 1, 2], [0, 2, 3]])
    else:  # one patch per triangle, its affine color field extended over the whole patch
        c0, c1, c2 = corner_colors[:, 0], corner_colors[:, 1], corner_colors[:, 2]
        texels = c0[:, None, None] * (1 - s)[None, ..., None] + c1[:, None, None] * (s - t)[None, ..., None] \
            + c2[:, None, None] * t[None, ..., None]
        centroids = scene.vertices[faces].mean(axis=1)
        corners = np.array([[0, 0], [1, 0], [1, 1]], np.float32)
        corner_idx = np.array([[0, 1, 2]])
    n = len(texels)
    order = np.argsort(_morton3(centroids), kind="stable")  # patch slot -> face group
    gx, gy = _atlas_grid(n)
    slot_x, slot_y = _morton2_decode(np.arange(n), gy)
    atlas = np.zeros((gy, gx, PATCH, PATCH, 3), np.uint8)
    atlas[slot_y, slot_x] = np.clip(np.round(texels[order]), 0, 255).astype(np.uint8)
    image = atlas.transpose(0, 2, 1, 3, 4).reshape(gy * PATCH, gx * PATCH, 3)
    # texture coordinates of each group's corners at its slot
    px = np.empty(n, np.int64)
    py = np.empty(n, np.int64)
    px[order], py[order] = slot_x, slot_y
    k = len(corners)
    span = PATCH - 2 * INSET
    u = (px[:, None] * PATCH + INSET + corners[None, :, 0] * span) / (gx * PATCH)
    v = (py[:, None] * PATCH + INSET + corners[None, :, 1] * span) / (gy * PATCH)
    texcoord = np.stack([u, v], axis=-1).reshape(-1, 2).astype(np.float32)
    face_tc = (np.arange(n)[:, None, None] * k + corner_idx[None]).reshape(-1, 3).astype(np.int32)
    return TextureAtlas(np.ascontiguousarray(image), texcoord, face_tc, MAX_MIP_LEVEL)


def _patch_coords() -> tuple[np.ndarray, np.ndarray]:
    """Face coordinates (s, t) of each texel center of a patch, indexed [row (t), column (s)];
    the face covers [0, 1]^2, outer texels lie beyond it."""
    a = ((np.arange(PATCH) + 0.5 - INSET) / (PATCH - 2 * INSET)).astype(np.float32)
    t, s = np.meshgrid(a, a, indexing="ij")
    return s, t


def _atlas_grid(n: int) -> tuple[int, int]:
    """Smallest power-of-two grid of patches, square or 2:1, holding n patches."""
    side = 1
    while side * side < n:
        if 2 * side * side >= n:
            return 2 * side, side
        side *= 2
    return side, side


def _spread(x: np.ndarray, dims: int) -> np.ndarray:
    """Interleave: bit i of x moves to bit dims*i."""
    out = np.zeros_like(x, dtype=np.uint64)
    x = x.astype(np.uint64)
    for i in range(21 if dims == 3 else 32):
        out |= ((x >> np.uint64(i)) & np.uint64(1)) << np.uint64(dims * i)
    return out


def _morton3(points: np.ndarray) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.int64)
    return _spread(q[:, 0], 3) | (_spread(q[:, 1], 3) << np.uint64(1)) | (_spread(q[:, 2], 3) << np.uint64(2))


def _morton2_decode(i: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Slot index along a Z curve -> (x, y); indices past side*side continue in a second square."""
    square, j = np.divmod(i.astype(np.int64), side * side)
    x = np.zeros_like(j)
    y = np.zeros_like(j)
    for b in range(max(1, int(side).bit_length())):
        x |= ((j >> (2 * b)) & 1) << b
        y |= ((j >> (2 * b + 1)) & 1) << b
    return x + square * side, y
