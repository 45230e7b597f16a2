"""Mesh quality against the ground-truth mesh: Accuracy, Completion, Chamfer distance, F-score.

Distances are exact point-to-triangle distances (Open3D's BVH, scene.surface_distance), not
distances between two point samples: with samples, a perfect reconstruction scores the samples'
own spacing (about 1.3 cm at 200k points in a furnished room), and a shift adds to it in
quadrature rather than in full.
  Accuracy   = mean distance from points sampled on the reconstruction to the ground-truth triangles;
  Completion = mean distance from the visible ground-truth samples to the reconstruction's triangles;
  Chamfer    = (Accuracy + Completion) / 2;
  F-score@t  = 2 P R / (P + R), P = share of reconstruction samples within t of the ground truth,
               R = share of ground-truth samples within t of the reconstruction (t = 5 cm).

The ground-truth samples are the visible part of the surface (flightrecon.evaluation.visible_surface);
every point of the reconstruction counts, so floating surface in front of the truth is an error.
"""

from __future__ import annotations

import numpy as np
import trimesh

from flightrecon.scene.surface_distance import SurfaceDistance


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """`count` area-uniform points on a triangle mesh (deterministic for the seed)."""
    if len(faces) == 0:
        return np.zeros((0, 3))
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(pts, float)


def distance_metrics(d_acc: np.ndarray, d_comp: np.ndarray, threshold: float = 0.05) -> dict:
    """Accuracy, Completion, Chamfer (meters), precision, recall and F-score at `threshold` from the
    reconstruction-to-truth distances `d_acc` and the truth-to-reconstruction distances `d_comp`."""
    if len(d_acc) == 0 or len(d_comp) == 0:
        return {"accuracy": float("nan"), "completion": float("nan"), "chamfer": float("nan"),
                "precision": 0.0, "recall": 0.0, "fscore": 0.0}
    acc, comp = float(d_acc.mean()), float(d_comp.mean())
    p, r = float((d_acc < threshold).mean()), float((d_comp < threshold).mean())
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return {"accuracy": acc, "completion": comp, "chamfer": 0.5 * (acc + comp), "precision": p,
            "recall": r, "fscore": f}


def surface_metrics(recon: trimesh.Trimesh, truth: SurfaceDistance, truth_points: np.ndarray, count: int,
                    threshold: float = 0.05) -> dict:
    """The module's metrics of reconstructed mesh `recon` against the ground-truth triangles `truth`
    and the visible ground-truth samples `truth_points`; `count` samples on the reconstruction."""
    if len(recon.faces) == 0:
        return distance_metrics(np.zeros(0), np.zeros(0), threshold)
    recon_points = sample_surface(np.asarray(recon.vertices), np.asarray(recon.faces), count, seed=0)
    return distance_metrics(truth.distance(recon_points), SurfaceDistance(recon).distance(truth_points), threshold)
