"""How much of the room a flight has seen, frame by frame: the share of the room's visible
ground-truth surface within reach of the captured depth, and each new frame's overlap with what
the earlier frames saw (both on a voxel grid, 5 cm by default)."""

from __future__ import annotations

import numpy as np

from flightrecon.geometry import backproject_depth
from flightrecon.mapping.voxel_hash import voxel_keys


class SurfaceCoverage:
    """Voxels of the visible ground-truth surface (points [M,3]) and of every captured depth point."""

    def __init__(self, surface_points: np.ndarray, voxel: float = 0.05) -> None:
        self.voxel = float(voxel)
        self.surface = np.unique(voxel_keys(surface_points, self.voxel))
        self.observed = np.zeros(0, np.int64)

    def get_state(self) -> dict:
        """The voxels the captured depth has reached; the surface is rebuilt from its points."""
        return {"observed": self.observed.copy()}

    def set_state(self, state: dict) -> None:
        self.observed = np.asarray(state["observed"], np.int64)

    def add_frame(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> tuple[float, float]:
        """(share of the surface voxels observed so far, share of this frame's voxels seen before)."""
        points, _ = backproject_depth(depth, K, T_wc)
        keys = np.unique(voxel_keys(points, self.voxel)) if len(points) else np.zeros(0, np.int64)
        overlap = float(np.isin(keys, self.observed, assume_unique=True).mean()) if len(keys) else float("nan")
        self.observed = np.union1d(self.observed, keys)
        seen = float(np.isin(self.surface, self.observed, assume_unique=True).mean()) if len(self.surface) else 0.0
        return seen, overlap
