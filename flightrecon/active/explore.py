"""`gaussmi2d_explore`: 2D GauSS-MI that also values space no camera has seen (beyond the paper).

The paper's MI (Eq. 22) sums over existing splats only, so a view of never-seen space is worth
nothing until a frame has put splats there; the diagnosis flights (results/diagnosis/) show the
paper's method reaching less of the room's surface than ActiveGS for that reason. This variant
treats the unknown space at the frontier of an occupancy map as surface not yet reconstructed:
each scoring pixel whose ray, after leaving the known free space, meets unknown space (rather than
an occupied voxel) within `selector.explore_range` counts as one more splat with the prior
reliability P0 = 0.5 (the paper's initial value) and full transmittance. Its gain is Eq. 21 with
that prior, -|w| log 0.5, where the unknown surface's normal is unknown: |w| is replaced by its
mean over isotropic normals, E|cos| = 1/2. The splats' MI is the paper's, unchanged.

The occupancy map is the selector's own (planning.occupancy.OccupancyMap at `selector.explore_voxel`,
a box of `selector.explore_extent` around the first camera), fed every captured depth frame; it
does not share the planner's, which may be the ground-truth scene. Rays start `hover_free_radius`
from the candidate, the space the planner proved free around a drone it accepts there.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flightrecon.active.protocol import Observation
from flightrecon.active.selectors import GaussMI2D
from flightrecon.config import ScenarioConfig
from flightrecon.geometry import pixel_rays
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.planning.occupancy import UNKNOWN, OccupancyMap

PRIOR_GAIN = -0.5 * math.log(0.5)  # -E|w| log P0 per pixel: Eq. 21 for unseen surface
CAMERAS_PER_CALL = 16  # candidates whose rays are marched together (bounds the sample array)


def frontier_pixels(occupancy: OccupancyMap, T_wc: np.ndarray, K: np.ndarray, width: int, height: int, *,
                    t_min: float, t_max: float, stride: int = 1) -> np.ndarray:
    """Per camera T_wc [C,4,4]: the pixels (of width x height with intrinsics K) whose ray first
    leaves free space into unknown space between t_min and t_max m. One ray every `stride` pixels
    in each direction stands for stride^2 pixels."""
    rays = pixel_rays(width, height, np.asarray(K, float))[stride // 2::stride, stride // 2::stride].reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    poses = np.asarray(T_wc, float).reshape(-1, 4, 4)
    counts = np.zeros(len(poses))
    for s in range(0, len(poses), CAMERAS_PER_CALL):
        P = poses[s:s + CAMERAS_PER_CALL]
        dirs = np.einsum("cij,rj->cri", P[:, :3, :3], rays).reshape(-1, 3)
        origins = np.repeat(P[:, :3, 3], len(rays), axis=0)
        first = occupancy.first_not_free(origins, dirs, t_min, t_max).reshape(len(P), len(rays))
        counts[s:s + len(P)] = (first == UNKNOWN).sum(axis=1) * stride * stride
    return counts


class GaussMI2DExplore(GaussMI2D):
    """The paper's 2D GauSS-MI plus the frontier gain of unseen space (module docstring)."""

    name = "gaussmi2d_explore"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.occupancy: OccupancyMap | None = None

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        diag = super().observe(mapper, obs)
        s = self.cfg.selector
        center = np.asarray(obs.T_wc, float)[:3, 3]
        if self.occupancy is None:
            half = 0.5 * np.asarray(s.explore_extent, float)
            self.occupancy = OccupancyMap(np.stack([center - half, center + half]), s.explore_voxel)
        self.occupancy.integrate(obs.depth, obs.K, obs.T_wc)
        self.occupancy.mark_free_sphere(center, self.cfg.planner.hover_free_radius)
        return diag

    def frontier_gain(self, poses: np.ndarray) -> np.ndarray:
        """The unseen-surface term [C] of each candidate camera T_wc [C,4,4], in MI units."""
        if self.occupancy is None:
            return np.zeros(len(poses))
        s = self.cfg.selector
        px = frontier_pixels(self.occupancy, poses, self.K_score.numpy(), s.scoring_width, s.scoring_height,
                             t_min=self.cfg.planner.hover_free_radius, t_max=s.explore_range,
                             stride=s.explore_stride)
        return PRIOR_GAIN * px

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        offset = torch.as_tensor(self.frontier_gain(poses), dtype=torch.float64)
        return self.mutual_information(mapper, poses, offset).numpy()
