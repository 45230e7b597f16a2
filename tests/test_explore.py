"""gaussmi2d_explore: the frontier ray query, the unseen-surface term, and its place in the loop."""

import csv
import math

import numpy as np
import pytest
import torch

from flightrecon.active.explore import PRIOR_GAIN, GaussMI2DExplore, frontier_entries, integrate_seen_space
from flightrecon.active.protocol import Observation
from flightrecon.active.registry import make_selector
from flightrecon.geometry import camera_pose, intrinsics, pixel_rays
from flightrecon.mission import Mission
from flightrecon.planning.occupancy import OCCUPIED, OccupancyMap
from flightrecon.scenario import load_config

TINY = ["camera.width=48", "camera.height=36", "selector.scoring_width=24", "selector.scoring_height=18",
        "mapper.k_new=5", "mapper.k_replay=2", "budget.frames=4", "budget.initial_views=1", "evaluation.views=2",
        "evaluation.every=0", "output.record=false", "selector.method=gaussmi2d_explore"]


def frontier_pixels(occ, T, K, W, H, *, stride=1, **kw) -> np.ndarray:
    """Pixels [C] whose rays count (one ray stands for stride^2 pixels)."""
    return np.isfinite(frontier_entries(occ, T, K, W, H, stride=stride, **kw)[..., 0]).sum(axis=1) * stride**2


def _half_known_room() -> OccupancyMap:
    """Free space for x < 2 (y < 0) or x < 1.9 (y >= 0); where y >= 0 a wall at x in [2, 2.1) behind a
    one-voxel band left unknown, as the occupancy update leaves in front of a seen surface; nothing
    seen where y < 0 beyond x = 2."""
    occ = OccupancyMap(np.array([[-1.0, -4.0, -1.0], [6.0, 4.0, 3.0]]), voxel_size=0.1)
    x = occ.origin[0] + (np.arange(occ.shape[0]) + 0.5) * 0.1
    y = occ.origin[1] + (np.arange(occ.shape[1]) + 0.5) * 0.1
    X, Y = np.meshgrid(x, y, indexing="ij")
    free = np.broadcast_to(((X < 2.0) & ((Y < 0) | (X < 1.9)))[..., None], occ.shape)
    wall = np.broadcast_to(((X > 2.0) & (X < 2.1) & (Y >= 0))[..., None], occ.shape)
    occ.observed[:] = free | wall
    occ.surface[:] = wall
    return occ


def test_unknown_ends_measures_the_unseen_space_each_ray_ends_in():
    occ = _half_known_room()
    o = np.array([[0.05, 0.05, 1.05]] * 4)
    d = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    o[1, 1] = -0.55  # along -y inside the free half
    o[2, 1] = -0.55  # along +x at y < 0: past x = 2 nothing was seen
    got, entry = occ.unknown_ends(o, d, t_min=0.0, t_max=3.0)
    assert got[0] == pytest.approx(0.1, abs=0.051)  # only the band in front of the wall
    assert got[1] == 0.0  # free all the way (y down to -3.55 stays inside the grid)
    assert got[2] == pytest.approx(3.05 - 2.0, abs=0.051)
    assert got[3] == pytest.approx(4.05 - 3.0, abs=0.051)  # straight up it leaves the grid: unknown
    assert entry[2] == pytest.approx(2.0 - 0.05, abs=0.051) and np.isnan(entry[1])
    assert occ.unknown_ends(o[:0], d[:0], 0.0, 3.0)[0].shape == (0,)
    occ.observed[occ._index(np.array([[2.55, -0.55, 1.05]]))[0].tolist()] = True  # a known voxel inside the unseen
    past, entry = occ.unknown_ends(o[2:3], d[2:3], t_min=0.0, t_max=3.0)
    assert past[0] == pytest.approx(3.05 - 2.6, abs=0.051)  # only the run after it: the space the ray ends in
    assert entry[0] == pytest.approx(2.6 - 0.05, abs=0.051)


def test_frontier_pixels_count_the_rays_into_unknown_space_not_the_band_before_a_wall():
    occ = _half_known_room()
    W, H = 40, 30
    K = intrinsics(W, H, 90.0)
    T = camera_pose(np.array([0.05, 0.05, 1.05]), 0.0)[None]  # looking along +x: left half of the image is y > 0
    kw = dict(t_min=0.3, min_unknown=0.3)
    full = frontier_pixels(occ, T, K, W, H, t_max=5.0, **kw)[0]
    assert full == pytest.approx(W * H / 2, rel=0.06)
    assert frontier_pixels(occ, T, K, W, H, t_max=5.0, min_unknown=0.05, t_min=0.3)[0] > 0.9 * W * H  # the band would
    strided = frontier_pixels(occ, T, K, W, H, t_max=5.0, stride=2, **kw)[0]
    assert strided == pytest.approx(full, rel=0.06)
    assert frontier_pixels(occ, T, K, W, H, t_max=1.5, **kw)[0] == 0  # the frontier is 2 m away
    away = camera_pose(np.array([0.05, 0.05, 1.05]), math.pi)[None]  # looking at -x: free, then out of range
    assert frontier_pixels(occ, away, K, W, H, t_max=0.9, **kw)[0] == 0


def test_a_pixel_without_depth_carves_free_space_out_to_the_range():
    occ = OccupancyMap(np.array([[-1.0, -3.0, -1.0], [8.0, 3.0, 3.0]]), voxel_size=0.1)
    W, H = 160, 120  # dense enough that the wall's hits leave no gap between voxels
    K = intrinsics(W, H, 90.0)
    T = camera_pose(np.array([0.05, 0.05, 1.05]), 0.0)
    depth = np.zeros((H, W), np.float32)
    depth[:, : W // 2] = 2.0  # a wall 2 m ahead on the left half; nothing within range on the right
    integrate_seen_space(occ, depth, K, T, beyond=5.2)
    right = camera_pose(np.array([0.05, 0.05, 1.05]), 0.0)[:3, :3] @ np.array([0.3, 0.0, 1.0])
    right = (right / np.linalg.norm(right))[None]
    left = camera_pose(np.array([0.05, 0.05, 1.05]), 0.0)[:3, :3] @ np.array([-0.3, 0.0, 1.0])
    left = (left / np.linalg.norm(left))[None]
    o = np.array([[0.05, 0.05, 1.05]])
    assert occ.unknown_ends(o, right, 0.3, 5.0)[0][0] == pytest.approx(0.0, abs=0.051)
    assert occ.unknown_ends(o, left, 0.3, 5.0)[0][0] <= 0.15  # up to the wall, then its band
    end = o + 5.2 * (T[:3, :3] @ np.array([0.3, 0.0, 1.0]))  # z-depth 5.2 m along a right-half ray
    assert occ.state(end)[0] != OCCUPIED  # where its carving ends no surface was seen


def _box_room_depth(T: np.ndarray, K: np.ndarray, W: int, H: int) -> np.ndarray:
    """Exact z-depth from camera T of a 5 x 5 x 2.6 m box room (x in [-1, 4], y in [-2.5, 2.5])."""
    rays = pixel_rays(W, H, K).reshape(-1, 3)
    d, o = rays @ T[:3, :3].T, T[:3, 3]
    hits = []
    for axis, plane in [(0, -1.0), (0, 4.0), (1, -2.5), (1, 2.5), (2, 0.0), (2, 2.6)]:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane - o[axis]) / d[:, axis]
        hits.append(np.where(t > 0, t, np.inf))
    return np.min(hits, axis=0).reshape(H, W).astype(np.float32)  # rays have z = 1: t is the z-depth


def test_a_view_just_integrated_sees_nothing_unseen_even_at_grazing_floors_and_ceilings():
    occ = OccupancyMap(np.array([[-1.5, -3.0, -0.5], [4.5, 3.0, 3.1]]), voxel_size=0.1)
    W, H = 160, 120
    K = intrinsics(W, H, 90.0)
    T = camera_pose(np.array([0.05, 0.05, 1.05]), 0.0)
    integrate_seen_space(occ, _box_room_depth(T, K, W, H), K, T, beyond=5.2)
    kw = dict(t_min=0.05, t_max=5.0, min_unknown=0.3)
    Ks = intrinsics(80, 60, 90.0)
    assert frontier_pixels(occ, T[None], Ks, 80, 60, **kw)[0] == 0  # the floor and ceiling run to 4 m at grazing angles
    behind = camera_pose(np.array([0.05, 0.05, 1.05]), math.pi)[None]
    assert frontier_pixels(occ, behind, Ks, 80, 60, **kw)[0] > 0.95 * 80 * 60  # nothing behind it was seen
    planner_map = OccupancyMap(occ.bounds, voxel_size=0.1)  # the footprint test, safe for flying, carves less
    planner_map.integrate(_box_room_depth(T, K, W, H), K, T, no_return=5.2)
    assert planner_map.observed.sum() < occ.observed.sum()


def _wall_observation(cfg, mission):
    """The tiny demo mission's first captured frame, mapped, as the selector sees it."""
    rgb, depth, T_wc, _ = mission.flight.capture(mission.rig.camera)
    mission.mapper.add_frame(rgb, depth, mission.rig.K, T_wc)
    return Observation(0, rgb, depth, mission.rig.K, T_wc)


def test_explore_score_is_the_papers_mi_plus_the_frontier_gain(tmp_path):
    cfg = load_config("demo", TINY)
    mission = Mission(cfg, tmp_path, progress=False)
    mission._take_off()
    obs = _wall_observation(cfg, mission)
    explore = make_selector(cfg)
    assert isinstance(explore, GaussMI2DExplore)
    assert explore.cfg.reliability.edge_mask and not cfg.reliability.edge_mask  # its own, not the config's
    explore.observe(mission.view, obs)
    T = obs.T_wc
    poses = np.stack([T, camera_pose(T[:3, 3], math.pi / 2), camera_pose(T[:3, 3], math.pi),
                      camera_pose(T[:3, 3], -math.pi / 2)])
    frontier = explore.frontier_gain(poses)
    assert frontier[2] > frontier[0]  # behind the first view lies unseen space
    units = frontier / (PRIOR_GAIN * cfg.explore.stride ** 2)  # whole rays of P0 = 0.5 surface
    np.testing.assert_allclose(units, np.round(units), atol=1e-9)
    got = explore.score(mission.view, poses)
    culled = explore.cfg
    explore.cfg = culled.with_section("reliability", gain_floor=0.0)  # the oracle: every MI exact
    mi = explore.mutual_information(mission.view, poses).numpy()
    explore.cfg = culled
    best = int(np.argmax(mi + frontier))
    assert int(np.argmax(got)) == best
    assert got[best] == pytest.approx(mi[best] + frontier[best], rel=1e-9)
    assert np.all(got <= mi + frontier + 1e-9 * np.abs(mi + frontier))  # others: a lower bound of the total


def test_explore_flies_a_closed_loop_and_its_diagnosis_splits_each_chosen_score(tmp_path):
    # every score exact (no floor), so the chosen one is its MI plus its frontier term
    cfg = load_config("demo", TINY + ["output.diagnose=true", "reliability.gain_floor=0"])
    metrics = Mission(cfg, tmp_path, progress=False).run()
    assert metrics["method"] == "gaussmi2d_explore" and metrics["frames"] == 4
    with open(tmp_path / "frames.csv", newline="") as fh:
        frames = list(csv.DictReader(fh))
    assert len(frames) == 4
    assert torch.isfinite(torch.tensor(metrics["eval"]["psnr"]))
    with open(tmp_path / "diagnosis.csv", newline="") as fh:
        chosen = [r for r in csv.DictReader(fh) if r["frontier"]]
    assert chosen
    for row in chosen:  # the split renders the MI itself (active/diagnosis.py), apart from the scoring kernel
        score = next(float(f["chosen_score"]) for f in frames if f["frame"] == row["frame"])
        assert float(row["mi"]) + float(row["frontier"]) == pytest.approx(score, rel=1e-4, abs=1e-6)
        units = float(row["frontier"]) / (PRIOR_GAIN * cfg.explore.stride ** 2)
        assert units == pytest.approx(round(units), rel=1e-5)  # whole rays into unseen space (csv rounding)
