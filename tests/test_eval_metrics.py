"""Rendering and mesh metrics against independent oracles (scikit-image, analytic geometry)."""

import numpy as np
import pytest
import torch
import trimesh
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from flightrecon.errors import DataError
from flightrecon.evaluation.lpips_metric import LpipsMetric
from flightrecon.evaluation.mesh_metrics import point_metrics, sample_surface
from flightrecon.evaluation.tsdf import fuse_depth_maps
from flightrecon.evaluation.view_store import load_views, save_views
from flightrecon.geometry import camera_pose, intrinsics
from flightrecon.mapping.image_metrics import depth_l1, psnr, ssim


def _images(seed=0):
    rng = np.random.default_rng(seed)
    a = rng.random((40, 50, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1).astype(np.float32)
    return a, b


def test_psnr_and_ssim_equal_scikit_image():
    a, b = _images()
    ref_psnr = peak_signal_noise_ratio(a, b, data_range=1.0)
    ref_ssim = structural_similarity(a, b, data_range=1.0, channel_axis=2, gaussian_weights=True, sigma=1.5,
                                     use_sample_covariance=False)
    assert float(psnr(torch.from_numpy(a), torch.from_numpy(b))) == pytest.approx(ref_psnr, abs=1e-4)
    # scikit-image averages SSIM over the window-valid interior too (it crops the 5-pixel border)
    assert float(ssim(torch.from_numpy(a), torch.from_numpy(b))) == pytest.approx(ref_ssim, abs=1e-4)


def test_depth_l1_of_a_known_offset_ignores_invalid_pixels():
    gt = torch.full((30, 40, 1), 2.0)
    gt[:10] = 0.0  # invalid ground truth
    pred = gt + 0.03
    pred[:10] = 5.0
    assert float(depth_l1(pred, gt)) == pytest.approx(0.03, abs=1e-6)


def test_lpips_without_local_weights_is_na_with_a_reason(tmp_path):
    m = LpipsMetric("")
    assert not m.available and "nothing is downloaded" in m.reason
    m = LpipsMetric(tmp_path / "missing.pth")
    assert not m.available and "not found" in m.reason


def _plane(size=2.0, z=0.0, n=20):
    """A flat square of 2 n^2 triangles in the plane at height z."""
    g = np.linspace(0, size, n + 1)
    xx, yy = np.meshgrid(g, g)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], 1)
    idx = np.arange(v.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_mesh_against_itself_is_perfect():
    v, f = _plane()
    p = sample_surface(v, f, 20000, seed=3)
    q = sample_surface(v, f, 20000, seed=3)
    m = point_metrics(p, q, 0.05)
    assert m["accuracy"] == 0.0 and m["completion"] == 0.0 and m["chamfer"] == 0.0 and m["fscore"] == 1.0


def test_mesh_shifted_by_two_cm_gives_the_known_numbers():
    v, f = _plane()
    truth = sample_surface(v, f, 20000, seed=3)
    recon = sample_surface(v + [0, 0, 0.02], f, 20000, seed=3)  # same samples, moved along the normal
    m = point_metrics(recon, truth, 0.05)
    assert m["accuracy"] == pytest.approx(0.02, abs=1e-9)
    assert m["completion"] == pytest.approx(0.02, abs=1e-9)
    assert m["chamfer"] == pytest.approx(0.02, abs=1e-9)
    assert m["fscore"] == 1.0  # every point within 5 cm
    assert point_metrics(recon, truth, 0.01)["fscore"] == 0.0  # none within 1 cm


def _box_depth(box: trimesh.Trimesh, T_wc, K, W, H):
    """Ground-truth z-depth of a mesh by trimesh ray casting (independent of our renderers)."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dirs_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    dirs_w = dirs_c @ T_wc[:3, :3].T
    origins = np.repeat(T_wc[:3, 3][None], len(dirs_w), 0)
    loc, ray, _ = box.ray.intersects_location(origins, dirs_w, multiple_hits=True)
    depth = np.full(len(dirs_w), np.inf)
    np.minimum.at(depth, ray, ((loc - origins[ray]) @ T_wc[:3, :3])[:, 2])  # nearest hit per ray
    depth[np.isinf(depth)] = 0.0
    return depth.reshape(H, W)


def test_tsdf_of_rendered_depth_recovers_a_box_within_a_voxel():
    half = np.array([0.4, 0.3, 0.25])
    box = trimesh.creation.box(extents=2 * half)
    W, H = 96, 72
    K = intrinsics(W, H, 90.0)
    poses, depths = [], []
    for k in range(8):
        yaw = 2 * np.pi * k / 8
        T = camera_pose(np.array([-1.3 * np.cos(yaw), -1.3 * np.sin(yaw), 0.4]), yaw, 10.0)
        poses.append(T)
        depths.append(_box_depth(box, T, K, W, H))
    voxel, trunc = 0.04, 0.12
    mesh = fuse_depth_maps(depths, np.stack(poses), K, voxel=voxel, truncation=trunc)
    assert len(mesh.faces) > 100
    # TSDF rounds sharp edges within the truncation distance (as Open3D's does): away from the box's
    # edges (at most one coordinate near a face) every vertex lies within a voxel of the surface
    v = mesh.vertices
    near_face = (np.abs(v) > half - trunc).sum(1)
    d = np.abs(trimesh.proximity.signed_distance(box, v[near_face <= 1]))
    assert len(d) > 100 and d.max() < voxel
    # and the seen side faces are covered: every sample of them has the mesh within a voxel
    side = sample_surface(np.asarray(box.vertices), np.asarray(box.faces), 4000, seed=0)
    side = side[np.abs(side[:, 2]) < half[2] - trunc]
    assert point_metrics(sample_surface(v, mesh.faces, 20000), side, voxel)["recall"] > 0.99


def test_view_store_round_trip_and_bad_file(tmp_path):
    poses = np.stack([camera_pose(np.array([1.0, 2.0, 1.2]), 0.3), camera_pose(np.array([0.0, 1.0, 1.0]), -1.0)])
    K = intrinsics(80, 60, 90.0)
    p = save_views(tmp_path / "room0.json", "room0", poses, K, 80, 60, seed=0)
    back = load_views(p)
    np.testing.assert_allclose(back["poses"], poses, atol=1e-8)
    assert back["scene"] == "room0" and back["width"] == 80
    (tmp_path / "bad.json").write_text('{"scene": "x"}')
    with pytest.raises(DataError, match="bad.json"):
        load_views(tmp_path / "bad.json")
