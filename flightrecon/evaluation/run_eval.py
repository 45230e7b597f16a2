"""Full evaluation of a finished run folder: rendering metrics, mesh metrics, model size.

Reads the run's config.toml and map.ply, rebuilds the scene's fixed evaluation views (the same
views the loop scored during the flight, flightrecon.evaluation.views), and writes
`eval.json`, `mesh.ply` (the TSDF mesh of the map) and `novel_view.npz` (the first evaluation
view's ground truth and renders, for the sweep's figures) into the run folder, and
`eval_over_frames.csv`: the same metrics for the map snapshots the flight saved at each in-flight
evaluation (`evaluation.every`), so mesh accuracy can be plotted over collected frames.

The mesh is fused (flightrecon.evaluation.tsdf) from the map's rendered depth (expected depth where
the rendered opacity exceeds 0.5) at a fixed dense set of views, the same for every method: six
90-degree cube faces at each of the first evaluation positions (one per floor-plan cell), so every
direction of the room is fused. It is compared with the part of the ground-truth surface visible
from the room's free space (flightrecon.evaluation.visible_surface), so completion measures the
whole room; every point of the fused mesh counts for accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh

from flightrecon.config import ScenarioConfig, load_config
from flightrecon.errors import FlightReconError
from flightrecon.evaluation.lpips_metric import LpipsMetric
from flightrecon.evaluation.mesh_metrics import point_metrics, sample_surface
from flightrecon.evaluation.tsdf import fuse_depth_maps
from flightrecon.evaluation.views import EvaluationSet, grid_size, mean_metrics, view_metrics
from flightrecon.evaluation.visible_surface import room_free_space, visible_surface
from flightrecon.fileio import atomic_path, write_json, write_text
from flightrecon.geometry import camera_pose, intrinsics, pixel_rays
from flightrecon.mapping.losses import normals_from_depth
from flightrecon.mapping.ply import load_map
from flightrecon.mapping.store import GaussianMap
from flightrecon.render import render

SNAPSHOTS = "snapshots"  # map_<frame>.ply saved by the flight at each in-flight evaluation
OVER_FRAMES = "eval_over_frames.csv"
OVER_FRAMES_KEYS = ("psnr", "depth_l1_cm", "accuracy_cm", "completion_cm", "chamfer_cm", "fscore")

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


@dataclass
class EvaluationTruth:
    """What a run is scored against: the evaluation views with their ground truth, the views the
    mesh is fused from, and the visible ground-truth surface."""

    views: EvaluationSet
    fusion_poses: np.ndarray  # [F,4,4]
    fusion_K: np.ndarray
    fusion_size: int  # square fusion images, fusion_size pixels a side
    surface_points: np.ndarray  # (M,3) samples of the ground-truth surface visible from the free space
    visible_area_m2: float
    total_area_m2: float


def fusion_poses(views: np.ndarray, positions: int) -> np.ndarray:
    """Six 90-degree cube faces (four headings, straight down, straight up) at each of the first
    `positions` evaluation view positions: the dense view set the TSDF mesh is fused from."""
    faces = [(yaw, 0.0) for yaw in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi)] + [(0.0, 90.0), (0.0, -90.0)]
    return np.stack([camera_pose(T[:3, 3], yaw, pitch) for T in views[:positions] for yaw, pitch in faces])


def _scene_setup(cfg: ScenarioConfig):
    """(scene, camera, workspace, take-off point, ground-truth distance field) as the loop builds them."""
    from flightrecon.mission import flight_region
    from flightrecon.planning.distance_field import DistanceField
    from flightrecon.scene.source import scene_from_config
    from flightrecon.sim.camera import RGBDCamera
    from flightrecon.sim.world import build_world

    c = cfg.camera
    scene = scene_from_config(cfg.scene)
    camera = RGBDCamera(build_world(scene, cfg), c.width, c.height, c.hfov_deg, c.near, c.far)
    workspace, start = flight_region(scene, cfg)
    pad = cfg.drone.body_radius + cfg.planner.safety_margin + 0.2
    truth = DistanceField.from_mesh(scene.trimesh, cfg.planner.voxel_size,
                                    workspace + np.array([[-pad], [pad]]), signed=False)
    return scene, camera, workspace, start, truth


def evaluation_views_for(cfg: ScenarioConfig) -> EvaluationSet:
    """The scene's evaluation views with their ground truth, as the loop builds them."""
    _, camera, workspace, start, truth = _scene_setup(cfg)
    return EvaluationSet.for_mission(camera, start, truth, workspace, cfg)


def evaluation_truth_for(cfg: ScenarioConfig) -> EvaluationTruth:
    """The evaluation views with ground truth, the fusion views and the visible ground-truth surface."""
    scene, camera, workspace, start, truth = _scene_setup(cfg)
    free = room_free_space(scene, start)
    views = EvaluationSet.for_mission(camera, start, truth, workspace, cfg, free)
    visible = visible_surface(scene, free, cfg.metrics.sample_points)
    size = cfg.camera.height
    return EvaluationTruth(views, fusion_poses(views.poses, grid_size(len(views.poses)) ** 2),
                           intrinsics(size, size, 90.0), size, visible.points,
                           visible.visible_area_m2, visible.total_area_m2)


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


def _nanmean(values: list[float]) -> float:
    v = [x for x in values if not np.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


def evaluate_map(gmap: GaussianMap, cfg: ScenarioConfig, truth: EvaluationTruth,
                 lpips: LpipsMetric | None) -> tuple[dict, dict, trimesh.Trimesh]:
    """(metrics, first-view renders, TSDF mesh) of a map: image metrics on the evaluation views,
    mesh metrics of its fusion at the fusion views against the visible ground truth."""
    r = MapRenderer(gmap, cfg.camera.near, cfg.camera.far, cfg.mapper.backend)
    ev = truth.views
    per_view, na, lp = [], [], []
    first: dict = {}
    for i, T in enumerate(ev.poses):
        out = r.render_view(T, ev.K, ev.width, ev.height, outputs=("features", "alpha", "depth", "normal"))
        color = out.features[0].clamp(0, 1)
        per_view.append(view_metrics(color, out.depth[0], out.alpha[0], ev.rgb[i], ev.depth[i]))
        na.append(normal_angle_error_deg(out.normal[0], ev.depth[i], ev.K))
        if lpips is not None and lpips.available:
            lp.append(lpips(color, ev.rgb[i]))
        if i == 0:
            first = {"gt_rgb": ev.rgb[0].numpy(), "gt_depth": ev.depth[0, ..., 0].numpy(),
                     "rgb": color.numpy(), "depth": out.depth[0, ..., 0].numpy(),
                     "normal": out.normal[0].numpy(), "psnr": per_view[0]["psnr"],
                     "depth_l1_cm": per_view[0]["depth_l1_cm"], "normal_err_deg": na[0]}
    depths = []
    for T in truth.fusion_poses:
        out = r.render_view(T, truth.fusion_K, truth.fusion_size, truth.fusion_size, outputs=("alpha", "depth"))
        d = torch.where(out.alpha[0] > SURFACE_ALPHA, out.depth[0], torch.zeros_like(out.depth[0]))
        depths.append(d[..., 0].numpy().astype(np.float64))
    m = cfg.metrics
    mesh = fuse_depth_maps(depths, truth.fusion_poses, truth.fusion_K, voxel=m.tsdf_voxel,
                           truncation=m.tsdf_truncation, max_depth=cfg.camera.far)
    rec_pts = sample_surface(mesh.vertices, mesh.faces, m.sample_points, seed=0)
    geo = point_metrics(rec_pts, truth.surface_points, m.fscore_threshold)
    metrics = {
        **mean_metrics(per_view),
        "lpips": float(np.mean(lp)) if lp else "n/a",
        "lpips_note": lpips.reason if lpips is not None else "not computed",
        "normal_err_deg": _nanmean(na),
        "accuracy_cm": 100 * geo["accuracy"], "completion_cm": 100 * geo["completion"],
        "chamfer_cm": 100 * geo["chamfer"], "precision": geo["precision"], "recall": geo["recall"],
        "fscore": geo["fscore"], "fscore_threshold_cm": 100 * m.fscore_threshold,
        "mesh_vertices": int(len(mesh.vertices)), "gt_points_visible": int(len(truth.surface_points)),
        "gt_visible_area_m2": truth.visible_area_m2, "gt_total_area_m2": truth.total_area_m2,
        "views": int(len(ev.poses)), "fusion_views": int(len(truth.fusion_poses)),
    }
    return metrics, first, trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def evaluate_run(run_dir: str | Path, lpips_weights: str | None = None, overrides: list[str] | tuple = ()) -> dict:
    """Evaluate `run_dir` (a finished flight), write eval.json, mesh.ply, novel_view.npz; return
    metrics. `overrides` (e.g. `evaluation.views=64`) change how it is scored, not the run."""
    run_dir = Path(run_dir)
    if not (run_dir / "map.ply").is_file():
        raise FlightReconError(f"{run_dir} has no map.ply: is the run finished?")
    cfg = load_config(run_dir / "config.toml", overrides)
    truth = evaluation_truth_for(cfg)
    lpips = LpipsMetric(lpips_weights if lpips_weights is not None else cfg.metrics.lpips_weights)
    metrics, first, mesh = evaluate_map(load_map(run_dir / "map.ply"), cfg, truth, lpips)
    metrics["model_mb"] = (run_dir / "map.ply").stat().st_size / 1e6
    with atomic_path(run_dir / "mesh.ply") as tmp:
        mesh.export(str(tmp), file_type="ply")
    with atomic_path(run_dir / "novel_view.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **first)
    _write_over_frames(run_dir, cfg, truth)
    write_json(run_dir / "eval.json", metrics)
    return metrics


def _write_over_frames(run_dir: Path, cfg: ScenarioConfig, truth: EvaluationTruth) -> None:
    """The metrics of OVER_FRAMES_KEYS (LPIPS, the costliest, is not among them) of the flight's map snapshots (mesh accuracy over collected frames for the report)."""
    snaps = sorted((run_dir / SNAPSHOTS).glob("map_*.ply"))
    rows = [",".join(("frame",) + OVER_FRAMES_KEYS)]
    for snap in snaps:
        m, _, _ = evaluate_map(load_map(snap), cfg, truth, None)
        rows.append(",".join([snap.stem.split("_")[1]] + [f"{m[k]:.6g}" for k in OVER_FRAMES_KEYS]))
    write_text(run_dir / OVER_FRAMES, "\n".join(rows) + "\n")
