"""The metrics of a map against a scene's ground truth: rendering metrics on the evaluation views
(with normal error and LPIPS) and mesh metrics of the map's TSDF fusion.

The mesh is fused (flightrecon.evaluation.tsdf) from the map's rendered depth (expected depth where
the rendered opacity exceeds 0.5) at a fixed dense set of views, the same for every method: six
90-degree cube faces at each of the first evaluation positions (one per floor-plan cell), so every
direction of the room is fused. It is compared with the part of the ground-truth surface visible
from the room's free space (flightrecon.evaluation.visible_surface), so completion measures the
whole room; every point of the fused mesh counts for accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from flightrecon.config import ScenarioConfig
from flightrecon.evaluation.lpips_metric import LpipsMetric
from flightrecon.evaluation.mesh_metrics import surface_metrics
from flightrecon.evaluation.tsdf import fuse_depth_maps
from flightrecon.evaluation.views import EvaluationSet
from flightrecon.geometry import camera_pose, pixel_rays
from flightrecon.mapping.losses import normals_from_depth
from flightrecon.mapping.store import GaussianMap
from flightrecon.metric_defs import cm
from flightrecon.render import RenderOutput, render
from flightrecon.scene.surface_distance import SurfaceDistance

SURFACE_ALPHA = 0.5  # rendered opacity above which a pixel's depth enters the TSDF


@dataclass
class MapRenderer:
    """Renders a saved map the way the loop's mapper does (the `render_view` EvaluationSet uses)."""

    map: GaussianMap
    near: float
    far: float
    backend: str = "auto"

    @torch.no_grad()
    def render_view(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int,
                    outputs: tuple[str, ...] = ("features", "alpha", "depth")):
        m = self.map
        viewmat = torch.as_tensor(np.linalg.inv(T_wc), dtype=torch.float32)[None]
        Ks = torch.as_tensor(K, dtype=torch.float32)[None]
        return render(m["means"], torch.nn.functional.normalize(m["quats"], dim=-1), m["log_scales"],
                      m["opacity_logits"], m["colors"], viewmat, Ks, width, height, near=self.near,
                      far=self.far, outputs=outputs, backend=self.backend)


def render_map(gmap: GaussianMap, T_wc: np.ndarray, K: np.ndarray, width: int, height: int, *,
               near: float = 0.05, far: float = 10.0,
               outputs: tuple[str, ...] = ("features", "alpha", "depth", "normal")) -> RenderOutput:
    """A map (e.g. `load_map` of a run's map.ply) rendered at camera-to-world T_wc [4,4] (OpenCV axes)
    with intrinsics K [3,3]: images [1,H,W,k] (features are the colors)."""
    return MapRenderer(gmap, near, far).render_view(np.asarray(T_wc, float), K, width, height, outputs)


@dataclass
class EvaluationTruth:
    """What a run is scored against: the evaluation views with their ground truth, the views the
    mesh is fused from, and the visible ground-truth surface."""

    views: EvaluationSet
    fusion_poses: np.ndarray  # [F,4,4]
    fusion_K: np.ndarray
    fusion_size: int  # square fusion images, fusion_size pixels a side
    surface: SurfaceDistance  # exact distance to the ground-truth triangles
    surface_points: np.ndarray  # (M,3) samples of the ground-truth surface visible from the free space
    visible_area_m2: float
    total_area_m2: float


def fusion_poses(views: np.ndarray, positions: int) -> np.ndarray:
    """Six 90-degree cube faces (four headings, straight down, straight up) at each of the first
    `positions` evaluation view positions: the dense view set the TSDF mesh is fused from."""
    faces = [(yaw, 0.0) for yaw in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi)] + [(0.0, 90.0), (0.0, -90.0)]
    return np.stack([camera_pose(T[:3, 3], yaw, pitch) for T in views[:positions] for yaw, pitch in faces])


def normal_angle_error_deg(normal: torch.Tensor, depth_gt: torch.Tensor, K: np.ndarray) -> float:
    """Mean angle (degrees) between rendered camera-frame normals [H,W,3] and the normals of the
    ground-truth depth [H,W,1], over pixels where both exist."""
    H, W = depth_gt.shape[:2]
    rays = torch.as_tensor(pixel_rays(W, H, K), dtype=torch.float32)
    n_gt = normals_from_depth(depth_gt, rays)
    n = torch.nn.functional.normalize(normal, dim=-1)
    ok = (n_gt.abs().sum(-1) > 0) & (normal.norm(dim=-1) > 0.5)
    if not bool(ok.any()):
        return float("nan")
    cos = (n * n_gt).sum(-1).abs().clamp(max=1.0)  # 2DGS normals face the camera: sign-free angle
    return float(torch.rad2deg(torch.acos(cos[ok])).mean())


def evaluate_map(source, cfg: ScenarioConfig, truth: EvaluationTruth,
                 lpips: LpipsMetric | None) -> tuple[dict, dict, trimesh.Trimesh]:
    """(metrics, first-view renders, TSDF mesh) of a map: image metrics on the evaluation views,
    mesh metrics of its fusion at the fusion views against the visible ground truth. `source` is a
    GaussianMap, rendered as the mapper renders it, or any renderer with the mapper's `render_view`
    (the ground truth itself, to hold the evaluation to a known answer)."""
    r = (MapRenderer(source, cfg.camera.near, cfg.camera.far, cfg.mapper.backend)
         if isinstance(source, GaussianMap) else source)
    ev = truth.views
    per_view = []
    first: dict = {}
    for i, out, color, metrics in ev.rendered_views(r, ("features", "alpha", "depth", "normal")):
        metrics["normal_err_deg"] = normal_angle_error_deg(out.normal[0], ev.depth[i], ev.K)
        if lpips is not None and lpips.available:
            metrics["lpips"] = lpips(color, ev.rgb[i])
        per_view.append(metrics)
        if i == 0:
            first = {"gt_rgb": ev.rgb[0].numpy(), "gt_depth": ev.depth[0, ..., 0].numpy(),
                     "rgb": color.numpy(), "depth": out.depth[0, ..., 0].numpy(),
                     "normal": out.normal[0].numpy(), "psnr": metrics["psnr"],
                     "depth_l1_cm": metrics["depth_l1_cm"], "normal_err_deg": metrics["normal_err_deg"]}
    depths = []
    for T in truth.fusion_poses:
        out = r.render_view(T, truth.fusion_K, truth.fusion_size, truth.fusion_size, outputs=("alpha", "depth"))
        d = torch.where(out.alpha[0] > SURFACE_ALPHA, out.depth[0], torch.zeros_like(out.depth[0]))
        depths.append(d[..., 0].numpy().astype(np.float64))
    m = cfg.metrics
    mesh = fuse_depth_maps(depths, truth.fusion_poses, truth.fusion_K, voxel=m.tsdf_voxel,
                           truncation=m.tsdf_truncation, max_depth=cfg.camera.far)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    geo = surface_metrics(mesh, truth.surface, truth.surface_points, m.sample_points, m.fscore_threshold)
    metrics = {
        "lpips": "n/a",  # replaced by the mean where LPIPS was computed
        **ev.aggregate(per_view),
        "lpips_note": lpips.reason if lpips is not None else "not computed",
        "accuracy_cm": cm(geo["accuracy"]), "completion_cm": cm(geo["completion"]),
        "chamfer_cm": cm(geo["chamfer"]), "precision": geo["precision"], "recall": geo["recall"],
        "fscore": geo["fscore"], "fscore_threshold_cm": cm(m.fscore_threshold),
        "mesh_vertices": int(len(mesh.vertices)), "gt_points_visible": int(len(truth.surface_points)),
        "gt_visible_area_m2": truth.visible_area_m2, "gt_total_area_m2": truth.total_area_m2,
        "fusion_views": int(len(truth.fusion_poses)),
    }
    return metrics, first, mesh
