"""A per-triangle texture atlas, and writing a mesh with it as OBJ + MTL + PNG.

Textured scans (Matterport, HM3D, many KinectFusion exports) carry their colour in an image that
UVs index, not on vertices. Any vertex-coloured mesh can be turned into one: each pair of triangles
gets its own small square cell of the image, one triangle in each corner, painted with the colours
interpolated across each triangle. No unwrapping is needed, and the loader's texture path is used.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from flightrecon.fileio import write_bytes

CELL = 4  # pixels on a side of each pair's square cell
_LEG = 2  # pixels along each leg of a triangle: A covers pixels with i + j <= 2, B those with i + j >= 4


def per_triangle_atlas(vertices: np.ndarray, faces: np.ndarray, vertex_colors: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (3F, 3), faces (F, 3), uv (3F, 2) with v = 0 at the image's bottom row, image
    (H, W, 3) uint8) showing the vertex colours (V, 3) uint8 of the triangles `faces`.

    In its pair's cell, triangle A (even) has its corners at the centres of pixels (0, 0), (2, 0)
    and (0, 2) (column, row) and triangle B (odd) at (3, 3), (1, 3) and (3, 1), so neither samples
    the other's colours at its corners."""
    faces = np.asarray(faces, np.int64)
    n = len(faces)
    cells = (n + 1) // 2
    cols = max(1, math.ceil(math.sqrt(cells)))
    rows = max(1, math.ceil(cells / cols))
    cell = np.arange(n) // 2
    origin = np.stack([(cell % cols) * CELL, (cell // cols) * CELL], 1)[:, None, :]  # top-left pixel
    a_corners = np.array([[0, 0], [_LEG, 0], [0, _LEG]])
    corners = np.where((np.arange(n) % 2 == 0)[:, None, None], a_corners, CELL - 1 - a_corners)
    px = origin + corners + 0.5  # (F, 3, 2) pixel centres (x, y from the top)
    W, H = cols * CELL, rows * CELL
    uv = np.stack([px[..., 0] / W, 1.0 - px[..., 1] / H], -1).reshape(-1, 2)
    image = _paint(np.asarray(vertex_colors, np.float64)[faces], cols, rows)
    return np.asarray(vertices, np.float64)[faces].reshape(-1, 3), np.arange(3 * n).reshape(n, 3), uv, image


def _paint(colors: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """The atlas image: each pixel of a cell gets the colour at its centre, interpolated across the
    triangle of the pair that covers it (`colors`: (F, 3 corners, 3) RGB); the pixels between the
    two (i + j = 3) take A's colour at the nearest point of its long side."""
    if len(colors) % 2:
        colors = np.concatenate([colors, colors[-1:]])
    pairs = colors.reshape(-1, 2, 3, 3)
    row, col = np.meshgrid(np.arange(CELL), np.arange(CELL), indexing="ij")

    def weights(i, j):  # barycentric weights of pixel centres in a triangle with legs along i and j
        w = np.clip(np.stack([1 - (i + j) / _LEG, i / _LEG, j / _LEG], -1), 0.0, None)
        return w / w.sum(-1, keepdims=True)
    in_a = (col + row <= CELL - 1)[None, ..., None]
    cell = np.where(in_a, np.einsum("ijk,nkc->nijc", weights(col, row), pairs[:, 0]),
                    np.einsum("ijk,nkc->nijc", weights(CELL - 1 - col, CELL - 1 - row), pairs[:, 1]))
    image = np.zeros((rows * cols, CELL, CELL, 3))
    image[:len(cell)] = cell
    image = image.reshape(rows, cols, CELL, CELL, 3).transpose(0, 2, 1, 3, 4).reshape(rows * CELL, cols * CELL, 3)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def write_textured_obj(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray,
                       image: np.ndarray) -> list[Path]:
    """Write path (.obj), its .mtl and its .png texture beside it, each atomically; returns the paths."""
    import trimesh
    from PIL import Image

    path = Path(path)
    # the material (and so the PNG) is named after the mesh, so several meshes can share a folder
    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(image), name=path.stem,
                                                      ambient=[255] * 4, diffuse=[255] * 4, specular=[0, 0, 0, 255])
    mesh = trimesh.Trimesh(vertices, faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=material))
    text, assets = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_color=False,
                                                   return_texture=True, mtl_name=path.stem + ".mtl", digits=6)
    written = [path]
    write_bytes(path, text.encode("utf-8"))
    for name, data in assets.items():
        write_bytes(path.parent / name, data)
        written.append(path.parent / name)
    return written
