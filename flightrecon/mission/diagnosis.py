"""output.diagnose: diagnosis.csv, one row per frame, to explain afterwards what each choice was.

Each frame adds the share of the room's visible surface the captured depth has reached and the new
frame's overlap with earlier ones (evaluation/coverage.py); each chosen view adds the move, the
best score over the median and the selector's own diagnosis (2D GauSS-MI: its MI split by kind of
splat, active/diagnosis.py). It records; it changes no choice.
"""

from __future__ import annotations

import math

import numpy as np

from flightrecon.active.diagnosis import move_kind
from flightrecon.active.protocol import MapView, Selector
from flightrecon.evaluation.coverage import SurfaceCoverage
from flightrecon.evaluation.visible_surface import visible_surface
from flightrecon.planning.feasibility import CandidateResult
from flightrecon.rig import Rig

SURFACE_SAMPLES = 200_000  # ground-truth surface samples of the coverage


def surface_coverage(rig: Rig) -> SurfaceCoverage:
    """The coverage of the surface visible from the room's free space, nothing seen yet."""
    return SurfaceCoverage(visible_surface(rig.scene, rig.free, SURFACE_SAMPLES).points)


def frame_row(coverage: SurfaceCoverage, frame: int, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> dict:
    """A frame's row: add its depth to the coverage; the share seen so far and the frame's overlap."""
    seen, overlap = coverage.add_frame(depth, K, T_wc)
    return {"frame": frame, "surface_seen": seen, "overlap": overlap}


def choice_columns(selector: Selector, view: MapView, position: np.ndarray, yaw: float, chosen: CandidateResult,
                   chosen_pose: np.ndarray, scores: np.ndarray) -> dict:
    """The chosen view's columns: the move from (`position`, `yaw`), the best score over the median
    and the selector's own diagnosis of the view (camera pose `chosen_pose`)."""
    median = np.median(scores)
    columns = {"move": move_kind(position, yaw, chosen.position, float(chosen.yaw)),
               "best_over_median": float(scores.max() / median) if median > 0 else math.nan}
    columns.update(selector.diagnose(view, chosen_pose))
    return columns
