"""Fixed evaluation viewpoints and the rendering metrics of a map on them.

The viewpoints are a seeded set per scene (seeded by the scene name and `evaluation.seed`, not by
the run's seed), so every method and every seed is scored on the same views. They are stratified
over the free space so that their mean measures the whole room: the floor plan of the flight
workspace is cut into a grid of cells that share the views evenly, headings into eight sectors
that do too, and a quarter of the views look 25 deg down and a quarter 25 deg up. Heights span the
flight workspace and `evaluation.height_margin` beyond it. A view is kept where the camera has
the drone's body radius of clearance on the ground-truth distance field and lies in the room's
free space (connected to the take-off point, not inside closed furniture; in an open scan, bounded
by its extent with its holes closed: flightrecon.scene.free_space); a cell without such a point
gives its views to the whole workspace. Their ground truth is rendered by the simulator's camera.

The evaluated space is the part of the free space that observed surface bounds: a view counts only
where its ground truth has depth (a surface within camera.far) on VALID_DEPTH_SHARE of its pixels.
A view that looks through a hole or over the walls of a scan without a ceiling would score the
map's empty background against the ground truth's, which says nothing of the map (and where both
are empty, rewards it). Such a pose is drawn again in its stratum (its cell, then the whole
workspace; its heading sector and pitch), so a scan keeps its view count where it can; a view that
no draw places is left out and counted (`views_dropped`). A closed room sees surface everywhere,
so its views are the first draws, as before this rule.

Every image metric is reported on all pixels and on covered pixels (rendered opacity >= 0.5), with
the covered share: never-covered pixels count in full in the first (fair: the map is missing
there) and not at all in the second (what the map that exists is worth).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from flightrecon.config import ScenarioConfig
from flightrecon.errors import SceneError
from flightrecon.geometry import camera_pose
from flightrecon.mapping.image_metrics import depth_l1, psnr, psnr_of_mse, ssim_map
from flightrecon.metric_defs import cm, mean_metrics
from flightrecon.scene.free_space import FreeSpace, room_free_space

_MAX_TRIES = 200  # positions drawn for one pose
POSE_TRIES = 16  # poses drawn for one view: half in its cell, half in the whole workspace
# a view counts where this share of its ground-truth pixels has depth: a window or the end of a wall
# in a corner of the image may be empty, a view into a hole or over open walls is not
VALID_DEPTH_SHARE = 0.9
HEADING_SECTORS = 8
PITCHES_DEG = (0.0, 25.0, 0.0, -25.0)  # positive looks down
COVERED_ALPHA = 0.5
SSIM_RADIUS = 5  # the SSIM window's half width: ssim_map covers the image less this border


def stratum(k: int, cells: int) -> tuple[int, int, float]:
    """(floor-plan cell, heading sector, pitch in deg) of view k: cells take views in turn, and the
    sector and pitch advance with each round so every cell sees several headings and pitches."""
    rnd = k // cells
    return k % cells, (k + rnd) % HEADING_SECTORS, PITCHES_DEG[rnd % len(PITCHES_DEG)]


def grid_size(views: int) -> int:
    """Cells per side of the floor-plan grid: about four views per cell."""
    return max(1, math.ceil(math.sqrt(views / 4)))


def evaluation_poses(scene, start: np.ndarray, truth_field, workspace: np.ndarray, cfg: ScenarioConfig,
                     free: FreeSpace | None = None,
                     accept: Callable[[np.ndarray], bool] | None = None) -> np.ndarray:
    """T_wc [V,4,4] of the scene's evaluation views (deterministic for scene name + evaluation.seed);
    `free` is the room's free space if the caller has it already. A pose `accept` rejects (one that
    sees too little surface) is drawn again; views that cannot be placed are left out, so V may be
    less than evaluation.views."""
    e = cfg.evaluation
    rng = np.random.default_rng([zlib.crc32(scene.name.encode()), e.seed])
    lo, hi = np.asarray(workspace, float)
    z_lo, z_hi = lo[2] - e.height_margin, hi[2] + e.height_margin
    free = free or room_free_space(scene, start)

    def usable(p: np.ndarray) -> bool:
        return bool(free.contains(p)[0]) and truth_field.distance(p[None])[0] > cfg.drone.body_radius

    g = grid_size(e.views)
    edges_x, edges_y = np.linspace(lo[0], hi[0], g + 1), np.linspace(lo[1], hi[1], g + 1)
    whole = (np.array([lo[0], lo[1], z_lo]), np.array([hi[0], hi[1], z_hi]))
    poses = []
    for k in range(e.views):
        cell, sector, pitch_deg = stratum(k, g * g)
        cx, cy = divmod(cell, g)
        box = (np.array([edges_x[cx], edges_y[cy], z_lo]), np.array([edges_x[cx + 1], edges_y[cy + 1], z_hi]))
        T = _place(rng, box, whole, usable, sector, pitch_deg, accept)
        if T is not None:
            poses.append(T)
    return np.stack(poses) if poses else np.zeros((0, 4, 4))


def _place(rng: np.random.Generator, cell: tuple, whole: tuple, usable, sector: int, pitch_deg: float,
           accept) -> np.ndarray | None:
    """The first pose drawn for a view that `accept`s (None: any): its position in its cell (in the
    whole workspace where the cell holds no usable point, and for the second half of the tries),
    its heading in its sector, at its pitch; None where none is found."""
    for attempt in range(POSE_TRIES):
        p = _draw(rng, cell, usable) if attempt < POSE_TRIES // 2 else None
        if p is None:
            p = _draw(rng, whole, usable)
        if p is None:
            return None  # no usable point anywhere
        T = camera_pose(p, (sector + rng.random()) * 2 * math.pi / HEADING_SECTORS - math.pi, pitch_deg)
        if accept is None or accept(T):
            return T
    return None


def _draw(rng: np.random.Generator, box: tuple[np.ndarray, np.ndarray], usable) -> np.ndarray | None:
    for _ in range(_MAX_TRIES):
        p = rng.uniform(box[0], box[1])
        if usable(p):
            return p
    return None


def sees_surface(depth: np.ndarray) -> bool:
    """Whether a ground-truth depth image (0: no surface within camera.far) has depth on
    VALID_DEPTH_SHARE of its pixels: the views that count."""
    d = np.asarray(depth)
    return float(np.mean(np.isfinite(d) & (d > 0))) >= VALID_DEPTH_SHARE


def view_metrics(color: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor, gt_rgb: torch.Tensor,
                 gt_depth: torch.Tensor) -> dict:
    """PSNR, SSIM and depth L1 (cm) of one rendered view [H,W,k] on all pixels and on covered ones
    (alpha >= 0.5; '_covered', NaN when none is), and the covered share of the pixels. PSNR is at
    most metric_defs.PSNR_MAX_DB (zero error scores the cap). A view empty in both render and ground
    truth scores the cap, SSIM 1 and depth L1 0 (no valid pixel): it says nothing of the map, which
    is why an evaluation set keeps only views that see surface (`sees_surface`)."""
    covered = alpha >= COVERED_ALPHA
    share = float(covered.float().mean())
    r = SSIM_RADIUS
    smap = ssim_map(color, gt_rgb, radius=r)
    out = {"psnr": float(psnr(color, gt_rgb)), "ssim": float(smap.mean()),
           "depth_l1_cm": cm(depth_l1(depth, gt_depth)), "covered_share": share}
    nan = math.nan
    if share == 0.0:
        return {**out, "psnr_covered": nan, "ssim_covered": nan, "depth_l1_cm_covered": nan}
    mse = ((color - gt_rgb).square() * covered).sum() / (covered.sum() * color.shape[-1])
    inner = covered[r:-r, r:-r].expand(-1, -1, color.shape[-1])
    valid = torch.isfinite(gt_depth) & (gt_depth > 0) & covered
    dl = (depth - torch.nan_to_num(gt_depth)).abs()[valid]
    return {**out, "psnr_covered": float(psnr_of_mse(mse)),
            "ssim_covered": float(smap[inner].mean()) if inner.any() else nan,
            "depth_l1_cm_covered": cm(dl.mean()) if len(dl) else nan}


@dataclass
class EvaluationSet:
    """Ground-truth RGB-D at the evaluation views, and the metrics of a map rendered there."""

    poses: np.ndarray  # [V,4,4]
    rgb: torch.Tensor  # [V,H,W,3]
    depth: torch.Tensor  # [V,H,W,1]
    K: np.ndarray
    width: int
    height: int

    dropped: int = 0  # views left out: no pose of theirs sees enough surface

    @classmethod
    def for_mission(cls, camera, start: np.ndarray, truth_field, workspace: np.ndarray,
                    cfg: ScenarioConfig, free: FreeSpace | None = None) -> "EvaluationSet":
        """The views whose ground truth, rendered by `camera`, sees surface (`sees_surface`)."""
        frames = []  # the renders of the accepted poses, in the order the poses come back

        def accept(T: np.ndarray) -> bool:
            rgb, depth = camera.render(T)
            if sees_surface(depth):
                frames.append((rgb, depth))
                return True
            return False

        scene = camera.world.scene
        poses = evaluation_poses(scene, start, truth_field, workspace, cfg, free, accept)
        if not len(poses):
            raise SceneError(f"no evaluation view of scene '{scene.name}' sees surface on {VALID_DEPTH_SHARE:.0%} "
                             "of its pixels: check the scan's up axis (scene.up_axis; `flightrecon scene info`), "
                             "and that its walls stand within camera.far of the workspace")
        rgb = torch.from_numpy(np.stack([f[0] for f in frames]))
        depth = torch.from_numpy(np.stack([f[1] for f in frames]))[..., None]
        return cls(poses, rgb, depth, camera.K, camera.width, camera.height, cfg.evaluation.views - len(poses))

    def rendered_views(self, renderer, outputs: tuple[str, ...] = ("features", "alpha", "depth")):
        """For each view: (index, the renderer's output there, its clamped color, its `view_metrics`).
        `renderer` has the mapper's `render_view(T_wc, K, width, height, outputs)`."""
        for i, T in enumerate(self.poses):
            out = renderer.render_view(T, self.K, self.width, self.height, outputs=outputs)
            color = out.features[0].clamp(0, 1).cpu()
            yield i, out, color, view_metrics(color, out.depth[0].cpu(), out.alpha[0].cpu(), self.rgb[i], self.depth[i])

    def evaluate(self, renderer) -> dict:
        """Mean view metrics (`view_metrics`: PSNR dB, SSIM, depth L1 cm on valid ground truth, on all
        and on covered pixels, covered share) over the views (`aggregate`)."""
        return self.aggregate([m for *_, m in self.rendered_views(renderer)])

    def aggregate(self, rows: list[dict]) -> dict:
        """Per-view metric rows averaged as `mean_metrics` does (with `views`: how many count), and
        `views_dropped`: the views left out for seeing too little surface."""
        return {**mean_metrics(rows), "views_dropped": self.dropped}

    @staticmethod
    def frame_quality(rendered, rgb: np.ndarray, depth: np.ndarray) -> tuple[float, float]:
        """PSNR (dB) and depth L1 (cm) of the map at a just-captured frame (training-view quality), from
        the map's render at the frame's pose (`rendered`: a RenderOutput with features and depth)."""
        color = rendered.features[0].detach().clamp(0, 1).cpu()
        p = float(psnr(color, torch.from_numpy(np.asarray(rgb, np.float32))))
        d = cm(depth_l1(rendered.depth[0].detach().cpu(), torch.from_numpy(np.asarray(depth, np.float32))[..., None]))
        return p, d
