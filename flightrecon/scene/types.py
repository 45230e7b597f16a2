"""The `Scene` every other part consumes: a z-up triangle mesh in meters with its appearance."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np


@dataclass(eq=False)
class Scene:
    """A loaded scene, already in the world frame (z up, meters).

    Appearance is one of: per-vertex colors, per-face colors, or UVs (per vertex) + a texture image.
    The same triangles are the ground-truth surface used for evaluation and clearance.
    """

    name: str
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64 triangles
    vertex_colors: np.ndarray | None = None  # (V, 3) uint8
    face_colors: np.ndarray | None = None  # (F, 3) uint8
    uv: np.ndarray | None = None  # (V, 2) float, with `texture`; OBJ convention: v = 0 is the image's bottom row
    texture: np.ndarray | None = None  # (H, W, 3) uint8
    vertex_normals: np.ndarray | None = None  # (V, 3) as stored in the file, if any
    source: Path | None = None
    source_up_axis: str = "z"
    meta: dict = field(default_factory=dict)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned [min, max] corners."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def appearance(self) -> str:
        if self.texture is not None and self.uv is not None:
            return "texture"
        if self.vertex_colors is not None:
            return "vertex colors"
        if self.face_colors is not None:
            return "face colors"
        return "none"

    @cached_property
    def trimesh(self):
        """Ground-truth surface as a trimesh.Trimesh (for proximity, ray casts, sampling)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)
