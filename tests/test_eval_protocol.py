"""The evaluation protocol: stratified views shared by every method and seed, metrics on all and on
covered pixels, the ground-truth surface visible from the free space, and the intervals of a
paired comparison."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from flightrecon.evaluation.intervals import mean_interval, paired_difference
from flightrecon.evaluation.views import HEADING_SECTORS, evaluation_poses, grid_size, view_metrics
from flightrecon.evaluation.visible_surface import visible_surface
from flightrecon.scenario import load_config
from flightrecon.scene.free_space import room_free_space
from flightrecon.rig import flight_region, truth_field
from flightrecon.scene.source import procedural_scene
from flightrecon.scene.types import Scene


@pytest.fixture(scope="module")
def room0():
    cfg = load_config("sweep_cpu", ["scene.name=room0"])
    scene = procedural_scene("room0", 0)
    workspace, takeoff = flight_region(scene, cfg)
    start = takeoff.hover
    truth = truth_field(scene, cfg, workspace)
    return cfg, scene, workspace, start, truth


def _poses(room0, *overrides):
    cfg, scene, workspace, start, truth = room0
    return evaluation_poses(scene, start, truth, workspace, load_config("sweep_cpu", ["scene.name=room0", *overrides]))


def test_views_cover_the_floor_plan_every_heading_and_pitch(room0):
    cfg, scene, workspace, start, truth = room0
    poses = _poses(room0)
    assert len(poses) == cfg.evaluation.views == 64
    pos, fwd = poses[:, :3, 3], poses[:, :3, 2]  # camera z axis: the viewing direction
    g = grid_size(len(poses))
    lo, hi = workspace
    cell = np.minimum(((pos[:, :2] - lo[:2]) / (hi[:2] - lo[:2]) * g).astype(int), g - 1)
    counts = np.zeros((g, g), int)
    np.add.at(counts, (cell[:, 0], cell[:, 1]), 1)
    assert (counts >= 2).all(), counts  # every region of the floor plan holds views
    heading = np.arctan2(fwd[:, 1], fwd[:, 0])
    sectors = np.bincount(((heading + math.pi) / (2 * math.pi) * HEADING_SECTORS).astype(int) % HEADING_SECTORS,
                          minlength=HEADING_SECTORS)
    assert (sectors >= 4).all(), sectors  # every heading sector too
    pitch = np.degrees(np.arcsin(-fwd[:, 2]))
    assert (pitch > 20).sum() >= 12 and (pitch < -20).sum() >= 12 and (np.abs(pitch) < 1).sum() >= 24
    assert (pos[:, 2] > lo[2] - 0.2).all() and (pos[:, 2] < hi[2] + 0.2).all()
    assert np.ptp(pos[:, 2]) > 0.5 * (hi[2] - lo[2])  # heights span the flight workspace
    assert (truth.distance(pos) > cfg.drone.body_radius).all()


def test_views_are_the_same_for_every_method_and_seed(room0):
    a = _poses(room0)
    for extra in (["seed=3"], ["selector.method=random"], ["selector.method=activegs", "seed=1"]):
        np.testing.assert_array_equal(a, _poses(room0, *extra))
    assert not np.array_equal(a, _poses(room0, "evaluation.seed=1"))


def test_view_metrics_on_all_and_on_covered_pixels_equal_skimage():
    rng = np.random.default_rng(0)
    H, W = 40, 52
    gt = rng.random((H, W, 3))
    pred = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1)
    alpha = np.ones((H, W, 1))
    alpha[:, :12] = 0.2  # a band the map never covered: rendered black
    pred[:, :12] = 0.0
    gt_depth = rng.uniform(1, 3, (H, W, 1))
    gt_depth[5:8] = 0.0  # invalid ground truth
    depth = gt_depth + 0.01
    depth[:, :12] = 0.0
    t = lambda a: torch.from_numpy(a)  # noqa: E731
    m = view_metrics(t(pred), t(depth), t(alpha), t(gt), t(gt_depth))
    assert m["covered_share"] == pytest.approx(40 / 52)
    assert m["psnr"] == pytest.approx(peak_signal_noise_ratio(gt, pred, data_range=1.0), abs=1e-9)
    cov = slice(12, None)
    assert m["psnr_covered"] == pytest.approx(peak_signal_noise_ratio(gt[:, cov], pred[:, cov], data_range=1.0), abs=1e-9)
    _, smap = structural_similarity(gt, pred, data_range=1.0, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, full=True)
    r = 5
    assert m["ssim"] == pytest.approx(smap[r:-r, r:-r].mean(), abs=1e-9)
    assert m["ssim_covered"] == pytest.approx(smap[r:-r, r:-r][:, 12 - r:].mean(), abs=1e-9)
    valid = gt_depth[..., 0] > 0
    expect_all = np.abs(depth - gt_depth)[..., 0][valid].mean()
    assert m["depth_l1_cm"] == pytest.approx(100 * expect_all, rel=1e-6)
    assert m["depth_l1_cm_covered"] == pytest.approx(1.0, rel=1e-6)  # 1 cm wherever covered and valid


def _box_room() -> tuple[Scene, float, float]:
    """A closed room with 0.2 m thick walls (inner and outer faces) and a cube standing on its floor:
    returns the scene, its visible area (inner faces less the cube's footprint, plus the cube's
    five free faces) and the hidden area (outer faces, the cube's bottom and the floor under it)."""
    inner = trimesh.creation.box(extents=(4.0, 3.0, 2.5))
    inner.invert()  # faces look into the room
    outer = trimesh.creation.box(extents=(4.4, 3.4, 2.9))
    cube = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    cube.apply_translation((0.8, 0.5, -1.25 + 0.3))
    mesh = trimesh.util.concatenate([inner, outer, cube])
    mesh.apply_translation((0.0, 0.0, 1.25))
    foot = 0.36
    visible = inner.area - foot + (cube.area - foot)
    return Scene("box", np.asarray(mesh.vertices), np.asarray(mesh.faces, np.int64)), visible, outer.area + 2 * foot


def test_visible_surface_of_a_box_room_is_its_inner_faces():
    scene, visible_area, hidden_area = _box_room()
    vis = visible_surface(scene, room_free_space(scene, np.array([-1.0, -0.8, 1.2])), 200_000)
    assert vis.total_area_m2 == pytest.approx(visible_area + hidden_area, rel=1e-9)
    assert vis.visible_area_m2 == pytest.approx(visible_area, rel=0.02)
    p = vis.points
    on_inner_walls = (np.abs(np.abs(p[:, 0]) - 2.0) < 1e-6) | (np.abs(np.abs(p[:, 1]) - 1.5) < 1e-6) \
        | (np.abs(p[:, 2] - 2.5) < 1e-6) | (np.abs(p[:, 2]) < 1e-6)
    on_cube = (np.abs(p[:, 0] - 0.8) <= 0.3 + 1e-6) & (np.abs(p[:, 1] - 0.5) <= 0.3 + 1e-6) & (p[:, 2] <= 0.6 + 1e-6)
    assert (on_inner_walls | on_cube).all()  # no outer face
    under_cube = on_cube & (np.abs(p[:, 2]) < 1e-6)
    assert under_cube.sum() < 1e-3 * len(p)  # the cube's bottom and the floor below it are hidden
    with pytest.raises(ValueError, match="not in the free space"):
        room_free_space(scene, np.array([30.0, 0.5, 0.3]))  # off the scene


def test_visible_surface_of_procedural_scenes_drops_hidden_faces():
    # the outer faces of walls and slabs (on the mesh's bounding box) and hidden furniture faces go
    scene = procedural_scene("room0", 0)
    lo, hi = scene.bounds
    vis = visible_surface(scene, room_free_space(scene, np.array([0.0, 0.0, 1.2])), 100_000)
    on_shell = ((np.abs(vis.points - lo) < 0.01) | (np.abs(vis.points - hi) < 0.01)).any(axis=1)
    assert not on_shell.any()
    assert 0.3 < vis.visible_area_m2 / vis.total_area_m2 < 0.6


def _synthetic_comparison(rng, seeds: int, noise: float, by_scene: float = 0.0) -> tuple[dict, dict]:
    """(theirs, ours) on 8 scenes x `seeds`: scene effects (sd 5) shared by both methods, a true
    difference of 0.5 that varies by scene with sd `by_scene`, and `noise` per run."""
    scene = rng.normal(0, 5, (8, 1))
    ours = scene + rng.normal(0, noise, (8, seeds))
    theirs = scene + 0.5 + (rng.normal(0, by_scene, (8, 1)) if by_scene else 0.0) + rng.normal(0, noise, (8, seeds))
    keys = [(s, k) for s in range(8) for k in range(seeds)]
    return {k: theirs[k] for k in keys}, {k: ours[k] for k in keys}


def test_paired_interval_covers_a_known_difference():
    # 2000 synthetic comparisons of 8 scenes x 3 seeds, noise 0.5 per run: the 95% paired interval
    # covers the true difference of 0.5 in ~95% of them.
    rng = np.random.default_rng(4)
    covered, excluded_zero = 0, 0
    for _ in range(2000):
        iv = paired_difference(*_synthetic_comparison(rng, seeds=3, noise=0.5))
        covered += iv.low <= 0.5 <= iv.high
        excluded_zero += iv.excludes_zero()
    assert 0.93 < covered / 2000 < 0.97
    assert excluded_zero / 2000 > 0.8  # 24 pairs tell a 0.5 difference from none
    one = mean_interval([1.0])
    assert one.mean == 1.0 and math.isnan(one.half_width) and one.format(2) == "1.00"
    assert mean_interval([1.0, 2.0, float("nan")]).n == 2


def test_paired_interval_over_scenes_covers_a_difference_that_varies_by_scene():
    # the difference itself varies by scene (sd 0.6) and two seeds share it: 16 pooled pairs are
    # not 16 independent samples of the mean difference, so their interval is too narrow; averaging
    # the seeds per scene and taking the interval over the 8 scenes keeps the promised 95%
    rng = np.random.default_rng(5)
    pooled, by_scene = 0, 0
    for _ in range(2000):
        a, b = _synthetic_comparison(rng, seeds=2, noise=0.3, by_scene=0.6)
        iv = paired_difference(a, b)
        pooled += iv.low <= 0.5 <= iv.high
        iv = paired_difference(a, b, unit=lambda k: k[0])
        by_scene += iv.low <= 0.5 <= iv.high
        assert iv.n == 8
    assert pooled / 2000 < 0.90
    assert 0.93 < by_scene / 2000 < 0.97


def test_the_stored_views_are_the_ones_the_loop_uses(room0):
    from flightrecon.evaluation.view_store import load_views, views_path

    stored = load_views(views_path("room0"))
    assert stored["scene"] == "room0" and stored["evaluation_seed"] == 0
    np.testing.assert_allclose(stored["poses"], _poses(room0), atol=1e-8)
