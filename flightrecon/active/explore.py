"""`gaussmi2d_explore`: 2D GauSS-MI that also values space no camera has seen (beyond the paper).

The paper's MI (Eq. 22) sums over existing splats only, so a view of never-seen space is worth
nothing until a frame has put splats there; the diagnosis flights (results/diagnosis/) show the
paper's method reaching less of the room's surface than ActiveGS for that reason. This variant
treats the unknown space at the frontier of an occupancy map as surface not yet reconstructed:
each scoring pixel whose ray ends in unknown space, within `explore.range` (the last UNKNOWN_VOXELS
before its first occupied voxel, or before the range, are unknown: the thin band left in front of
every seen surface does not count, nor unseen space the ray leaves again), counts as one more
splat with the prior reliability P0 = 0.5 (the paper's initial value) and full transmittance. Its gain is Eq. 21 with
that prior, -|w| log 0.5, where the unknown surface's normal is unknown: |w| is replaced by its
mean over isotropic normals, E|cos| = 1/2. The splats' MI is the paper's.

Its reliability update leaves the depth and normal terms out at occlusion edges of the observed
depth (reliability.edge_mask, the `gaussmi2d_edge` ablation): with the frontier term alone, on one
of four held-out scene variants the drone re-captured the same view 29 times in 60 frames, drawn
by splats whose evidence at occlusion edges stayed negative (93% of the chosen views' MI, 76% of it
on edge pixels); with the mask it did not (results/ranking/dev_sceneseed1).

The occupancy map is the selector's own (planning.occupancy.OccupancyMap at `explore.voxel`,
a box of `explore.extent` around the first camera), fed every captured depth frame by ray casting
(`integrate_rays`); it does not share the planner's, which may be the ground-truth scene. The
planner's footprint test, safe for flying, leaves space uncarved wherever a voxel's footprint also
holds nearer pixels: near every floor and ceiling seen at a grazing angle and along the image's
edges. Counted as unseen, that space drew the drone back to views it had already taken. A pixel with no depth return saw
no surface within the camera's range, so its ray carves free space out to `explore.range` (the
planner's map, more careful, carves nothing there); without that, space seen through a window or
door would stay unknown and draw the drone forever. Rays start at the camera's near plane: a
candidate may hover closer to a wall than any fixed radius (the planner keeps only the required
clearance), and a ray started behind the wall would count the unseen space beyond it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from flightrecon.active.protocol import MapView, Observation
from flightrecon.active.selectors import GaussMI2D
from flightrecon.config import ScenarioConfig, option
from flightrecon.geometry import pixel_rays
from flightrecon.planning.occupancy import OccupancyMap

PRIOR_GAIN = -0.5 * math.log(0.5)  # -E|w| log P0 per pixel: Eq. 21 for unseen surface
UNKNOWN_VOXELS = 3  # unknown space a ray must end in to count: more than the uncarved band of about one
# voxel that the occupancy update leaves in front of every seen surface
CAMERAS_PER_CALL = 16  # candidates whose rays are marched together (bounds the sample array)


@dataclass(frozen=True)
class ExploreConfig:
    """`[explore]`: the frontier term of gaussmi2d_explore (its reliability and MI read `[reliability]`)."""

    voxel: float = option(0.1, 0.02, 1.0, doc="voxel of its own occupancy map (m)")
    extent: list = option([16.0, 16.0, 5.0], doc="occupancy grid size around the first camera (m)")
    range: float = option(5.0, 0.1, 100.0, doc="unknown space farther than this along a scoring ray is worth "
                          "nothing (m)")
    stride: int = option(4, 1, 64, doc="one frontier ray per this many scoring pixels in each direction, "
                         "weighted by the pixels it stands for")
    moved_from = {"selector.explore_voxel": "voxel", "selector.explore_extent": "extent",
                  "selector.explore_range": "range", "selector.explore_stride": "stride"}


def frontier_entries(occupancy: OccupancyMap, T_wc: np.ndarray, K: np.ndarray, width: int, height: int, *,
                     t_min: float, t_max: float, min_unknown: float, stride: int = 1) -> np.ndarray:
    """Per camera T_wc [C,4,4], one ray every `stride` pixels in each direction of width x height
    (intrinsics K): the world point [C,R,3] where the ray enters the unknown space it ends in, when
    that space is at least `min_unknown` m long between t_min and t_max m
    (OccupancyMap.unknown_ends); nan for a ray that does not count."""
    rays = pixel_rays(width, height, np.asarray(K, float))[stride // 2::stride, stride // 2::stride].reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    poses = np.asarray(T_wc, float).reshape(-1, 4, 4)
    entries = np.full((len(poses), len(rays), 3), np.nan)
    for s in range(0, len(poses), CAMERAS_PER_CALL):
        P = poses[s:s + CAMERAS_PER_CALL]
        dirs = np.einsum("cij,rj->cri", P[:, :3, :3], rays).reshape(-1, 3)
        origins = np.repeat(P[:, :3, 3], len(rays), axis=0)
        unknown, t = occupancy.unknown_ends(origins, dirs, t_min, t_max)
        t = np.where(unknown >= min_unknown, t, np.nan)
        entries[s:s + len(P)] = (origins + dirs * t[:, None]).reshape(len(P), len(rays), 3)
    return entries


def integrate_seen_space(occupancy: OccupancyMap, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray,
                         beyond: float) -> None:
    """Add a depth frame to the occupancy map; a pixel with no return (0) saw no surface within the
    camera's range, so its ray carves free space out to `beyond` m (and marks no surface there)."""
    occupancy.integrate_rays(depth, K, T_wc, no_return=beyond)


class GaussMI2DExplore(GaussMI2D):
    """The paper's 2D GauSS-MI plus the frontier gain of unseen space (module docstring)."""

    name = "gaussmi2d_explore"
    section, settings = "explore", ExploreConfig

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg.with_section("reliability", edge_mask=True))
        self.occupancy: OccupancyMap | None = None

    def observe(self, view: MapView, obs: Observation) -> dict:
        diag = super().observe(view, obs)
        s = self.cfg.explore
        center = np.asarray(obs.T_wc, float)[:3, 3]
        if self.occupancy is None:
            half = 0.5 * np.asarray(s.extent, float)
            self.occupancy = OccupancyMap(np.stack([center - half, center + half]), s.voxel)
        integrate_seen_space(self.occupancy, obs.depth, obs.K, obs.T_wc, s.range + 2 * s.voxel)
        self.occupancy.mark_free_sphere(center, self.cfg.drone.body_radius)  # its own body proves this empty
        return diag

    def frontier_entries(self, poses: np.ndarray) -> np.ndarray:
        """`frontier_entries` [C,R,3] of candidate cameras T_wc [C,4,4] at the scoring resolution, one
        ray per `explore.stride` pixels in each direction."""
        s, c = self.cfg.explore, self.cfg.selector
        if self.occupancy is None:
            return np.full((len(poses), 0, 3), np.nan)
        return frontier_entries(self.occupancy, poses, self.K_score.numpy(), c.scoring_width, c.scoring_height,
                                t_min=self.cfg.camera.near, t_max=s.range, min_unknown=UNKNOWN_VOXELS * s.voxel,
                                stride=s.stride)

    def frontier_gain(self, poses: np.ndarray, entries: np.ndarray | None = None) -> np.ndarray:
        """The unseen-surface term [C] of each candidate camera T_wc [C,4,4], in MI units: a ray stands
        for stride^2 pixels. `entries`: their `frontier_entries`, when already marched."""
        entries = self.frontier_entries(poses) if entries is None else entries
        return PRIOR_GAIN * self.cfg.explore.stride ** 2 * np.isfinite(entries[..., 0]).sum(axis=1)

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        offset = torch.as_tensor(self.frontier_gain(poses), dtype=torch.float64)
        return self.mutual_information(view, poses, offset).numpy()

    def diagnose(self, view: MapView, T_wc: np.ndarray) -> dict:
        """The paper's MI split (GaussMI2D.diagnose) and the chosen view's frontier term (`frontier`):
        the two parts of its score, so a choice drawn back to seen surface shows which part drew it."""
        return {**super().diagnose(view, T_wc), "frontier": float(self.frontier_gain(np.asarray(T_wc)[None])[0])}

    def get_state(self) -> dict:
        if self.occupancy is None:
            return {}
        return {"bounds": self.occupancy.bounds, "occupancy": self.occupancy.get_state()}

    def set_state(self, state: dict) -> None:
        if state:
            self.occupancy = OccupancyMap(np.asarray(state["bounds"]), self.cfg.explore.voxel)
            self.occupancy.set_state(state["occupancy"])
