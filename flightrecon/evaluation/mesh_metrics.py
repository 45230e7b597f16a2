"""Mesh quality against the ground-truth mesh: Accuracy, Completion, Chamfer distance, F-score.

Both meshes are sampled densely (area-uniform, seeded, the same number of points) and compared
with scipy KD-trees:
  Accuracy   = mean distance from reconstructed points to the nearest ground-truth point;
  Completion = mean distance from ground-truth points to the nearest reconstructed point;
  Chamfer    = (Accuracy + Completion) / 2;
  F-score@t  = 2 P R / (P + R), P = share of reconstructed points within t of the ground truth,
               R = share of ground-truth points within t of the reconstruction (t = 5 cm).

The ground-truth points are the visible part of the surface (flightrecon.evaluation.visible_surface);
every point of the reconstruction counts, so floating surface in front of the truth is an error.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree



def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """`count` area-uniform points on a triangle mesh (deterministic for the seed)."""
    if len(faces) == 0:
        return np.zeros((0, 3))
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(pts, float)


def point_metrics(recon: np.ndarray, truth: np.ndarray, threshold: float = 0.05) -> dict:
    """Accuracy, Completion, Chamfer (meters), precision, recall and F-score at `threshold`."""
    if len(recon) == 0 or len(truth) == 0:
        return {"accuracy": float("nan"), "completion": float("nan"), "chamfer": float("nan"),
                "precision": 0.0, "recall": 0.0, "fscore": 0.0}
    d_acc = cKDTree(truth).query(recon, workers=-1)[0]
    d_comp = cKDTree(recon).query(truth, workers=-1)[0]
    acc, comp = float(d_acc.mean()), float(d_comp.mean())
    p, r = float((d_acc < threshold).mean()), float((d_comp < threshold).mean())
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return {"accuracy": acc, "completion": comp, "chamfer": 0.5 * (acc + comp), "precision": p,
            "recall": r, "fscore": f}
