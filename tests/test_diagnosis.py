"""The diagnosis of a flight: MI split by kind of splat (parts sum to the MI the selector scores),
occlusion edges, move kinds, surface coverage, and diagnosis.csv from a real flight."""

import csv
import math

import numpy as np
import pytest
import torch

from flightrecon.active import gaussmi2d
from flightrecon.active.diagnosis import KINDS, mi_split, move_kind, splat_kinds
from flightrecon.active.reliability import depth_edges
from flightrecon.evaluation.coverage import SurfaceCoverage
from flightrecon.geometry import camera_pose, intrinsics
from flightrecon.mission import Mission
from flightrecon.scenario import load_config
from splat_scenes import wall

W, H = 24, 18
K = torch.tensor(intrinsics(W, H, 90.0), dtype=torch.float32)


def test_kinds_follow_the_observed_sides_log_odds():
    w = torch.tensor([-0.5, -0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.05])
    rel = torch.tensor([[3.0, 0.0], [3.0, 2.0], [0.0, 0.0], [-1.0, 0.0], [2.0, 0.0], [7.0, 0.0], [10.0, 0.0],
                        [1.0, 1.0]])
    kinds = splat_kinds(w, rel, 0.1, 10.0)
    assert [KINDS[k] if k >= 0 else "edge-on" for k in kinds.tolist()] == [
        "back_unseen", "back_seen", "front_unseen", "negative", "weak", "strong", "clamped", "edge-on"]


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_split_sums_to_the_scored_mi(backend):
    s = wall(4)
    N = len(s["means"])
    rel = torch.linspace(-2.0, 10.0, 2 * N).reshape(N, 2)
    rel[::3, 0] = 0.0
    T = torch.tensor(camera_pose(np.array([0.2, 0.1, 1.1]), 0.1), dtype=torch.float32)
    split = mi_split(s, rel, T, K, W, H, w_min=0.1, clamp=10.0, near=0.05, far=10.0, backend=backend)
    mi = gaussmi2d.score_candidates(s, rel, T[None], K, W, H, w_min=0.1, near=0.05, far=10.0, backend=backend)
    assert split["mi"] == pytest.approx(float(mi[0]), rel=1e-5)
    assert sum(split[f"mi_{k}"] for k in KINDS) == pytest.approx(split["mi"], rel=1e-9)
    assert split["mi_front_unseen"] > 0 and split["mi_weak"] > 0
    assert 0.0 <= split["mi_edge_share"] <= 1.0


def test_edges_are_depth_steps_and_holes():
    d = torch.ones(6, 8)
    d[:, 4:] = 2.0
    d[0, 0] = 0.0
    e = depth_edges(d)
    assert e[:, 3].all() and e[:, 4].all() and not e[3, 1] and e[0, 1] and e[1, 0]


def test_move_kinds():
    p = np.zeros(3)
    assert move_kind(p, 0.0, p + 0.05, 0.1) == "stay"
    assert move_kind(p, 0.0, p, math.radians(45)) == "turn"
    assert move_kind(p, 0.0, p + np.array([0.6, 0, 0]), 0.0) == "step"
    assert move_kind(p, math.pi - 0.01, p, -math.pi + 0.01) == "stay"  # wraps


def test_coverage_counts_what_the_depth_reached_and_the_overlap():
    g = np.meshgrid(np.linspace(-1, 1, 81), np.linspace(0.2, 2.2, 81))
    wall = np.stack([np.full(g[0].size, 2.0), g[0].ravel(), g[1].ravel()], 1)  # the plane x = 2
    cov = SurfaceCoverage(wall)
    T = camera_pose(np.array([0.0, 0.0, 1.2]), 0.0)
    Kn = intrinsics(40, 30, 60.0)
    depth = np.full((30, 40), 2.0, np.float32)  # z-depth of the plane x = 2 seen head-on
    seen, overlap = cov.add_frame(depth, Kn, T)
    assert 0.1 < seen < 1.0 and overlap == 0.0
    seen2, overlap2 = cov.add_frame(depth, Kn, T)
    assert seen2 == seen and overlap2 == 1.0
    assert math.isnan(cov.add_frame(np.zeros((30, 40), np.float32), Kn, T)[1])


@pytest.mark.slow
def test_diagnosed_flight_writes_a_row_per_frame(tmp_path):
    cfg = load_config("demo", ["camera.width=80", "camera.height=60", "selector.scoring_width=40",
                               "selector.scoring_height=30", "mapper.k_new=6", "mapper.k_replay=2",
                               "evaluation.views=2", "evaluation.every=0", "budget.frames=5",
                               "budget.initial_views=2", "output.record=false", "output.diagnose=true"])
    Mission(cfg, tmp_path, progress=False).run()
    with open(tmp_path / "diagnosis.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["frame"]) for r in rows] == list(range(5))
    seen = [float(r["surface_seen"]) for r in rows]
    assert all(0 < a <= b <= 1 for a, b in zip(seen, seen[1:]))
    chosen = [r for r in rows if r.get("mi")]
    assert chosen and all(r["move"] in ("stay", "turn", "step") for r in chosen)
    for r in chosen:
        parts = sum(float(r[f"mi_{k}"]) for k in KINDS)
        assert parts == pytest.approx(float(r["mi"]), rel=1e-4)
