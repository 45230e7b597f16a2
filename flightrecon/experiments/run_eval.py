"""Full evaluation of a finished run folder: rendering metrics, mesh metrics, model size.

Reads the run's config.toml and map.ply, rebuilds the scene's fixed evaluation views (the same
views the loop scored during the flight, flightrecon.evaluation.views), and writes
`eval.json`, `mesh.ply` (the TSDF mesh of the map) and `novel_view.npz` (the first evaluation
view's ground truth and renders, for the sweep's figures) into the run folder, and
`eval_over_frames.csv`: the same metrics for the map snapshots the flight saved at each in-flight
evaluation (`evaluation.every`), so mesh accuracy can be plotted over collected frames. The
metrics themselves are flightrecon.evaluation.map_metrics.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flightrecon import provenance, run_folder
from flightrecon.config import ScenarioConfig
from flightrecon.errors import FlightReconError
from flightrecon.evaluation.lpips_metric import LpipsMetric
from flightrecon.evaluation.map_metrics import EvaluationTruth, evaluate_map, fusion_poses
from flightrecon.evaluation.views import EvaluationSet, grid_size
from flightrecon.evaluation.visible_surface import visible_surface
from flightrecon.fileio import atomic_path, write_json, write_text
from flightrecon.geometry import intrinsics
from flightrecon.mapping.ply import load_map
from flightrecon.metric_defs import select
from flightrecon.rig import build_rig
from flightrecon.scenario import load_config
from flightrecon.scene.surface_distance import SurfaceDistance

OVER_FRAMES = select("psnr", "depth_l1_cm", "accuracy_cm", "completion_cm", "chamfer_cm", "fscore")


def evaluation_views_for(cfg: ScenarioConfig) -> EvaluationSet:
    """The scene's evaluation views with their ground truth, as the loop builds them."""
    return build_rig(cfg).evaluation_set()


def evaluation_truth_for(cfg: ScenarioConfig) -> EvaluationTruth:
    """The evaluation views with ground truth, the fusion views and the visible ground-truth surface."""
    rig = build_rig(cfg)
    views = rig.evaluation_set()
    visible = visible_surface(rig.scene, rig.free, cfg.metrics.sample_points)
    size = cfg.camera.height
    return EvaluationTruth(views, fusion_poses(views.poses, grid_size(cfg.evaluation.views) ** 2),
                           intrinsics(size, size, 90.0), size, SurfaceDistance(rig.scene.trimesh), visible.points,
                           visible.visible_area_m2, visible.total_area_m2)


def evaluate_run(run_dir: str | Path, lpips_weights: str | None = None, overrides: list[str] | tuple = ()) -> dict:
    """Evaluate `run_dir` (a finished flight), write eval.json, mesh.ply, novel_view.npz; return
    metrics. `overrides` (e.g. `evaluation.views=64`) change how it is scored, not the run."""
    run_dir = Path(run_dir)
    if not (run_dir / run_folder.MAP).is_file():
        raise FlightReconError(f"{run_dir} has no map.ply: is the run finished?")
    cfg = load_config(run_dir / run_folder.CONFIG, overrides)
    truth = evaluation_truth_for(cfg)
    lpips = LpipsMetric(lpips_weights if lpips_weights is not None else cfg.metrics.lpips_weights)
    metrics, first, mesh = evaluate_map(load_map(run_dir / run_folder.MAP), cfg, truth, lpips)
    metrics["model_mb"] = (run_dir / run_folder.MAP).stat().st_size / 1e6
    metrics["evaluated_with"] = provenance.code_state().label  # the flight's own code is in provenance.json
    with atomic_path(run_dir / run_folder.MESH) as tmp:
        mesh.export(str(tmp), file_type="ply")
    with atomic_path(run_dir / run_folder.NOVEL_VIEW) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **first)
    _write_over_frames(run_dir, cfg, truth)
    write_json(run_dir / run_folder.EVAL, metrics)
    return metrics


def _write_over_frames(run_dir: Path, cfg: ScenarioConfig, truth: EvaluationTruth) -> None:
    """The metrics of OVER_FRAMES (LPIPS, the costliest, is not among them) of the flight's map snapshots
    (mesh accuracy over collected frames for the report)."""
    snaps = sorted((run_dir / run_folder.SNAPSHOTS).glob("map_*.ply"))
    rows = [",".join(["frame"] + [k.key for k in OVER_FRAMES])]
    for snap in snaps:
        m, _, _ = evaluate_map(load_map(snap), cfg, truth, None)
        rows.append(",".join([run_folder.snapshot_frame(snap)] + [f"{m[k.key]:.6g}" for k in OVER_FRAMES]))
    write_text(run_dir / run_folder.OVER_FRAMES, "\n".join(rows) + "\n")
