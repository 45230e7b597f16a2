"""Mapping a recorded RGB-D dataset as if in flight, and scoring the map on its views.

Shared by `flightrecon map` (which writes the results) and `flightrecon bench map` (which times it).
Frames are fed in recording order, one `add_frame` each, except the held-out ones: with holdout k,
frames k-1, 2k-1, ... (every k-th, never the first) are kept for evaluation only.

A held-out pixel whose surface no training view saw cannot be rendered right by any mapper, so the
held-out scores are also given on the covered pixels (`training_coverage`): that separates a gap in
the survey from a gap in fitting.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from flightrecon.config import ScenarioConfig
from flightrecon.dataset import Dataset, Frame
from flightrecon.geometry import backproject_depth, project_points
from flightrecon.mapping.image_metrics import depth_l1, psnr, ssim
from flightrecon.mapping.mapper import FrameStats, OnlineMapper
from flightrecon.metric_defs import cm


def split_holdout(n: int, holdout: int) -> tuple[list[int], list[int]]:
    """(train, test) frame indices; holdout 0 trains on everything."""
    if holdout <= 0:
        return list(range(n)), []
    test = [i for i in range(n) if i % holdout == holdout - 1]
    return [i for i in range(n) if i % holdout != holdout - 1], test


@dataclass
class TrainResult:
    mapper: OnlineMapper
    train: list[int]
    test: list[int]
    seconds: list[float] = field(default_factory=list)  # add_frame wall time per training frame


def train_on_dataset(ds: Dataset, cfg: ScenarioConfig, holdout: int = 5, limit: int | None = None,
                     on_frame: Callable[[int, int, FrameStats, float], None] | None = None) -> TrainResult:
    """Feed the training frames to a fresh OnlineMapper in order; `on_frame(k, total, stats, s)` reports."""
    n = len(ds) if limit is None else min(len(ds), limit)
    train, test = split_holdout(n, holdout)
    mapper = OnlineMapper(cfg.mapper, near=cfg.camera.near, far=cfg.camera.far, seed=cfg.seed)
    result = TrainResult(mapper, train, test)
    for k, i in enumerate(train):
        f = ds[i]
        t0 = time.perf_counter()
        stats = mapper.add_frame(f.rgb, f.depth, f.K, f.T_wc)
        result.seconds.append(time.perf_counter() - t0)
        if on_frame is not None:
            on_frame(k, len(train), stats, result.seconds[-1])
    return result


def evaluate_view(mapper: OnlineMapper, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray,
                  T_wc: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """PSNR, SSIM and depth L1 (cm, over valid observed depth) of the map at one view, and the renders."""
    H, W = depth.shape[:2]
    out = mapper.render_view(T_wc, K, W, H, outputs=("features", "alpha", "depth"))
    color = out.features[0].clamp(0.0, 1.0).cpu().double()
    d = out.depth[0].cpu().double()
    obs_rgb = torch.from_numpy(np.asarray(rgb, np.float64))
    obs_d = torch.from_numpy(np.asarray(depth, np.float64))[..., None]
    obs_d = torch.where(obs_d <= mapper.far, obs_d, torch.zeros_like(obs_d))
    metrics = {"psnr": float(psnr(color, obs_rgb)), "ssim": float(ssim(color, obs_rgb)),
               "depth_l1_cm": cm(depth_l1(d, obs_d))}
    return metrics, color.numpy(), d[..., 0].numpy()


def training_coverage(view: Frame, training: list[Frame], max_footprint: float = 1.5, rel_tol: float = 0.02,
                      abs_tol: float = 0.03) -> np.ndarray:
    """(H, W) mask of the view's valid-depth pixels whose surface point a training frame saw at least as sharply.

    Each pixel is back-projected with the view's depth and projected into every training frame; it is
    covered where it lands inside that frame with a depth within max(abs_tol, rel_tol * z) of the
    depth the frame observed there (so a point hidden behind another surface does not count), seen
    with a pixel footprint at most `max_footprint` times the view's own (focal length over depth: a
    wall seen only from across the room cannot be rendered sharp from close up); inf: seen at all.
    """
    points, valid = backproject_depth(view.depth, view.K, view.T_wc)
    footprint = view.depth[valid] / view.K[0, 0]
    seen = np.zeros(len(points), bool)
    for f in training:
        H, W = f.depth.shape
        uv, z = project_points(points, f.K, f.T_wc)
        u, v = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        obs = np.zeros_like(z)
        obs[inside] = f.depth[v[inside].astype(int), u[inside].astype(int)]
        seen |= (inside & (obs > 0) & (np.abs(obs - z) <= np.maximum(abs_tol, rel_tol * z))
                 & (z / f.K[0, 0] <= max_footprint * footprint))
    mask = np.zeros(valid.shape, bool)
    mask[valid] = seen
    return mask


def masked_metrics(color: np.ndarray, depth: np.ndarray, rgb: np.ndarray, observed: np.ndarray,
                   mask: np.ndarray) -> dict:
    """PSNR and depth L1 (cm) of renders against observations over the pixels in `mask` only."""
    if not mask.any():
        return {"psnr": float("nan"), "depth_l1_cm": float("nan")}

    def pixels(x: np.ndarray) -> torch.Tensor:  # the masked pixels as a one-row image [1, P, C]
        x = np.asarray(x, np.float64)[mask]
        return torch.from_numpy(x.reshape(1, len(x), -1))

    return {"psnr": float(psnr(pixels(color), pixels(rgb))),
            "depth_l1_cm": cm(depth_l1(pixels(depth), pixels(observed)))}
