"""Fixed evaluation viewpoints and the rendering metrics of a map on them.

The viewpoints are a seeded set per scene (seeded by the scene name and `evaluation.seed`, not by
the run's seed), so every method and every seed is scored on the same views: free-space poses at
flight height (take-off height +- `evaluation.height_band`) with uniformly random heading, kept
only where the ground-truth distance field leaves the drone's body radius + safety margin. Their
ground truth is rendered by the simulator's camera.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from flightrecon.config import ScenarioConfig
from flightrecon.geometry import camera_pose
from flightrecon.mapping.image_metrics import depth_l1, psnr, ssim

_MAX_TRIES = 200


def evaluation_poses(scene_name: str, truth_field, workspace: np.ndarray, flight_z: float,
                     cfg: ScenarioConfig) -> np.ndarray:
    """T_wc [V,4,4] of the scene's evaluation views (deterministic for scene name + evaluation.seed);
    heights are `flight_z` (the take-off height) +- evaluation.height_band, inside the workspace."""
    e = cfg.evaluation
    rng = np.random.default_rng([zlib.crc32(scene_name.encode()), e.seed])
    lo, hi = np.asarray(workspace, float)
    need = cfg.drone.body_radius + cfg.planner.safety_margin
    poses = []
    for _ in range(e.views * _MAX_TRIES):
        p = np.array([rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]),
                      np.clip(flight_z + rng.uniform(-e.height_band, e.height_band), lo[2], hi[2])])
        yaw = rng.uniform(-math.pi, math.pi)
        if truth_field.distance(p[None])[0] > need:
            poses.append(camera_pose(p, yaw, cfg.camera.pitch_deg))
            if len(poses) == e.views:
                break
    if not poses:
        raise ValueError(f"no free evaluation viewpoint found in the workspace of scene '{scene_name}'")
    return np.stack(poses)


@dataclass
class EvaluationSet:
    """Ground-truth RGB-D at the evaluation views, and the metrics of a map rendered there."""

    poses: np.ndarray  # [V,4,4]
    rgb: torch.Tensor  # [V,H,W,3]
    depth: torch.Tensor  # [V,H,W,1]
    K: np.ndarray
    width: int
    height: int

    @classmethod
    def for_mission(cls, camera, truth_field, workspace: np.ndarray, flight_z: float,
                    cfg: ScenarioConfig) -> "EvaluationSet":
        poses = evaluation_poses(camera.world.scene.name, truth_field, workspace, flight_z, cfg)
        frames = [camera.render(T) for T in poses]
        rgb = torch.from_numpy(np.stack([f[0] for f in frames]))
        depth = torch.from_numpy(np.stack([f[1] for f in frames]))[..., None]
        return cls(poses, rgb, depth, camera.K, camera.width, camera.height)

    def evaluate(self, mapper) -> dict:
        """Mean PSNR (dB), SSIM and depth L1 (cm, on valid ground truth) over the views."""
        ps, ss, dl = [], [], []
        for i, T in enumerate(self.poses):
            out = mapper.render_view(T, self.K, self.width, self.height, outputs=("features", "depth"))
            color = out.features[0].clamp(0, 1).cpu()
            ps.append(float(psnr(color, self.rgb[i])))
            ss.append(float(ssim(color, self.rgb[i])))
            dl.append(100.0 * float(depth_l1(out.depth[0].cpu(), self.depth[i])))
        return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "depth_l1_cm": float(np.mean(dl)),
                "views": len(self.poses)}

    @staticmethod
    def frame_quality(mapper, obs) -> tuple[float, float]:
        """PSNR (dB) and depth L1 (cm) of the map at a just-captured frame (training-view quality)."""
        H, W = obs.depth.shape
        out = mapper.render_view(obs.T_wc, obs.K, W, H, outputs=("features", "depth"))
        color = out.features[0].clamp(0, 1).cpu()
        p = float(psnr(color, torch.from_numpy(np.asarray(obs.rgb, np.float32))))
        d = 100.0 * float(depth_l1(out.depth[0].cpu(), torch.from_numpy(np.asarray(obs.depth, np.float32))[..., None]))
        return p, d
