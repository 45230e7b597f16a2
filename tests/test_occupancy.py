"""Occupancy map from depth: surfaces occupied, rays free, the unseen unknown; checked against the
true mesh with rays cast independently by trimesh (different pixels than the depth image's)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from flightrecon.geometry import backproject_depth, camera_pose, intrinsics, pixel_rays
from flightrecon.planning.distance_field import DistanceField
from flightrecon.planning.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from flightrecon.scenario import load_config

H = 0.05


def _room() -> trimesh.Trimesh:
    room = trimesh.creation.box(extents=[6.0, 5.0, 3.0])
    room.apply_translation([0.0, 0.0, 1.5])
    room.invert()
    crate = trimesh.creation.box(extents=[0.8, 1.0, 1.0])
    crate.apply_translation([1.5, 0.0, 0.8])
    return trimesh.util.concatenate([room, crate])


def _raycast_depth(mesh, K, T_wc, width, height) -> np.ndarray:
    """z-depth image by trimesh ray casting (0 where no hit)."""
    rays = pixel_rays(width, height, K).reshape(-1, 3)
    dirs = rays @ T_wc[:3, :3].T
    origins = np.repeat(T_wc[None, :3, 3], len(dirs), axis=0)
    loc, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    depth = np.zeros(len(rays))
    depth[ray_idx] = ((loc - T_wc[:3, 3]) @ T_wc[:3, :3])[:, 2]
    return depth.reshape(height, width).astype(np.float32)


def _probe_rays(mesh, T_wc, K, width, height, n, rng):
    """Independent rays through random (non-center) pixel positions: origins, unit dirs, hit ranges.

    The outer 10% of the image is left out: a voxel whose center falls just outside the image is
    (rightly) not carved even if a ray through its corner was seen."""
    uv = rng.uniform([0.1 * width, 0.1 * height], [0.9 * width, 0.9 * height], (n, 2))
    d_cam = np.concatenate([(uv - K[:2, 2]) / np.diag(K)[:2], np.ones((n, 1))], axis=1)
    dirs = d_cam @ T_wc[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.repeat(T_wc[None, :3, 3], n, axis=0)
    loc, idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    rng_hit = np.full(n, np.nan)
    rng_hit[idx] = np.linalg.norm(loc - origins[idx], axis=1)
    ok = np.isfinite(rng_hit)
    return origins[ok], dirs[ok], rng_hit[ok]


def _assert_surfaces_occupied_rays_free(occ, mesh, probes):
    origins, dirs, ranges = probes
    hits = origins + dirs * ranges[:, None]
    # Every surface point lies within a voxel of an occupied voxel (the field of the occupied set
    # reads center distance minus half a voxel).
    occupied_field = DistanceField.from_blocked(occ.occupied(), occ.origin, H, signed=False)
    assert np.mean(occupied_field.distance(hits) <= H) > 0.98
    # Points along the rays are free, except within a voxel or so of a surface.
    fr = np.random.default_rng(1).uniform(0.1, 0.9, len(ranges))
    mids = origins + dirs * (fr * ranges)[:, None]
    _, d_surf, _ = trimesh.proximity.ProximityQuery(mesh).on_surface(mids)
    away = (d_surf > 2 * H) & (fr * ranges > 0.2)
    assert away.sum() > 50
    assert np.mean(occ.state(mids[away]) == FREE) > 0.97  # the rest: voxel centers behind an edge
    # Behind the surfaces nothing was seen.
    behind = hits + dirs * 0.4
    inside_room = np.all(np.abs(behind[:, :2]) < [2.9, 2.4], axis=1) & (behind[:, 2] > 0.1) & (behind[:, 2] < 2.9)
    assert np.mean(occ.state(behind[inside_room]) != FREE) > 0.97


def test_synthetic_depth_marks_surfaces_occupied_rays_free_and_the_rest_unknown():
    mesh = _room()
    w, h = 96, 72
    K = intrinsics(w, h, 90.0)
    occ = OccupancyMap(np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]]), H)
    T = camera_pose([-0.5, 0.2, 1.2], 0.0)
    occ.integrate(_raycast_depth(mesh, K, T, w, h), K, T)
    _assert_surfaces_occupied_rays_free(occ, mesh, _probe_rays(mesh, T, K, w, h, 400, np.random.default_rng(0)))
    # Behind the camera nothing is known; the crate's hidden interior stays unknown.
    assert occ.state(np.array([[-2.0, 0.2, 1.2]]))[0] == UNKNOWN
    assert occ.state(np.array([[1.6, 0.0, 0.8]]))[0] == UNKNOWN
    # Unknown counts as blocked for planning; the free sphere of the body becomes free.
    field = occ.distance_field()
    assert field.distance(np.array([[-2.0, 0.2, 1.2]]))[0] < 0
    occ.mark_free_sphere(np.array([-0.5, 0.2, 1.2]), 0.4)
    assert occ.state(np.array([[-0.5, 0.2, 1.55], [-0.85, 0.2, 1.2]])).tolist() == [FREE, FREE]


def test_invalid_depth_carves_nothing_and_a_repeated_view_changes_nothing():
    mesh = _room()
    w, h = 64, 48
    K = intrinsics(w, h, 90.0)
    T = camera_pose([0.0, 0.0, 1.2], np.pi)
    depth = _raycast_depth(mesh, K, T, w, h)
    occ = OccupancyMap(np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]]), H)
    occ.integrate(np.zeros_like(depth), K, T)
    assert not occ.observed.any()
    occ.integrate(depth, K, T)
    occupied = occ.occupied()
    occ.integrate(depth, K, T)
    np.testing.assert_array_equal(occ.occupied(), occupied)  # the same view confirms, never erodes


def test_a_measured_surface_is_never_carved_by_later_rays():
    """A thin table top seen once stays an obstacle though later rays pass its voxels (as rays through
    voxel centers do at a rim seen at a grazing angle): a hit is proof in a static scene."""
    room = _room()
    top = trimesh.creation.box(extents=[1.0, 1.0, 0.03])
    top.apply_translation([0.6, 0.0, 0.78])
    w, h = 64, 48
    K = intrinsics(w, h, 90.0)
    T = camera_pose([-0.8, 0.0, 1.2], 0.0)
    occ = OccupancyMap(np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]]), H)
    occ.integrate(_raycast_depth(trimesh.util.concatenate([room, top]), K, T, w, h), K, T)
    rim = occ.occupied() & ~_occupied_by(room, K, T, w, h)
    assert rim.sum() > 20
    without_top = _raycast_depth(room, K, T, w, h)
    for _ in range(5):
        occ.integrate(without_top, K, T)
    assert occ.occupied()[rim].all()


def test_a_surface_seen_by_one_pixel_keeps_its_neighbours_from_being_carved():
    """Voxels beside a one-pixel surface, whose own center pixel sees the far wall, may hold the rest of
    that surface (a rim, a pole between pixels): a voxel is carved only if its whole footprint saw past it."""
    w, h = 64, 48
    K = intrinsics(w, h, 90.0)
    T = camera_pose([0.0, 0.0, 1.2], 0.0)
    depth = np.full((h, w), 3.0, np.float32)
    depth[24, 32] = 1.0  # a thin object seen by one pixel
    occ = OccupancyMap(np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]]), H)
    occ.integrate(depth, K, T)
    spike = backproject_depth(depth, K, T)[0][24 * w + 32]
    assert occ.state(spike[None])[0] == OCCUPIED
    side = T[:3, 0]  # the camera's x axis, in the world
    beside = spike + np.outer([-1.0, 1.0], side) * H
    assert (occ.state(beside) != FREE).all()
    assert (occ.state(spike + np.outer([-1.0, 1.0], side) * 0.5) == FREE).all()  # far from it: carved
    assert occ.state((T[:3, 3] + 0.6 * (spike - T[:3, 3]))[None])[0] == FREE  # in front of it: carved


def _occupied_by(mesh, K, T, w, h) -> np.ndarray:
    occ = OccupancyMap(np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]]), H)
    occ.integrate(_raycast_depth(mesh, K, T, w, h), K, T)
    return occ.occupied()


@pytest.mark.slow
def test_occupancy_from_rendered_depth_marks_surfaces_occupied_and_rays_free():
    from flightrecon.scene.source import procedural_scene
    from flightrecon.sim.camera import RGBDCamera
    from flightrecon.sim.world import build_world

    cfg = load_config(None, ["scene.name=room0"])
    scene = procedural_scene("room0", 0)
    mesh = scene.trimesh
    world = build_world(scene, cfg, with_drone=False)
    w, h = 160, 120
    cam = RGBDCamera(world, w, h, 90.0, 0.05, 10.0)
    occ = OccupancyMap(np.array(scene.meta["room_box"]) + np.array([[-0.4], [0.4]]), H)
    rng = np.random.default_rng(0)
    probes = []
    for k in range(4):
        T = camera_pose([0.0, 0.0, 1.2], k * np.pi / 2)
        _, depth = cam.render(T)
        occ.integrate(depth, cam.K, T)
        probes.append(_probe_rays(mesh, T, cam.K, w, h, 150, rng))
    cam.close()
    origins, dirs, ranges = (np.concatenate(x) for x in zip(*probes))
    _assert_surfaces_occupied_rays_free(occ, mesh, (origins, dirs, ranges))


def test_bad_frames_are_data_errors_and_nan_depth_is_invalid():
    from flightrecon.errors import DataError

    mesh = _room()
    w, h = 64, 48
    K = intrinsics(w, h, 90.0)
    T = camera_pose([0.0, 0.0, 1.2], 0.0)
    box = np.array([[-3.3, -2.8, -0.3], [3.3, 2.8, 3.3]])
    occ = OccupancyMap(box, H)
    with pytest.raises(DataError, match="HxW depth"):
        occ.integrate(np.zeros((h, w, 1)), K, T)
    bad_T = T.copy()
    bad_T[0, 3] = np.nan
    with pytest.raises(DataError, match="NaN"):
        occ.integrate(np.zeros((h, w)), K, bad_T)
    depth = _raycast_depth(mesh, K, T, w, h)
    holes = depth.copy()
    holes[:, : w // 2] = np.nan  # the left half unusable
    occ.integrate(holes, K, T)
    ref = OccupancyMap(box, H)
    half = depth.copy()
    half[:, : w // 2] = 0.0
    ref.integrate(half, K, T)
    np.testing.assert_array_equal(occ.observed, ref.observed)
    np.testing.assert_array_equal(occ.surface, ref.surface)


def _wall_view(free_range: float = np.inf, camera_x: float = 0.0) -> OccupancyMap:
    """A 160x120, 90 deg camera at (camera_x, 0, 0) looking along +z at a wall 3 m away (constant z-depth)."""
    K = intrinsics(160, 120, 90.0)  # f = 80 px, principal point (80, 60)
    occ = OccupancyMap(np.array([[-3.0, -3.0, -1.0], [3.0, 3.0, 4.0]]), H, free_range=free_range)
    T = np.eye(4)
    T[0, 3] = camera_x
    occ.integrate(np.full((120, 160), 3.0, np.float32), K, T)
    return occ


def test_a_voxel_reaching_past_the_image_border_is_not_carved():
    """By hand: the voxel centered at (0.325, 0.025, 0.325) spans 12.3 px (f = 80) at its depth. Seen
    from x = -0.012 its center projects 3 px beyond the right border (column 163), from x = +0.012 3 px
    inside it (157): either way part of it lies outside the field of view, where no ray looked (a table
    top just below the image's edge was carved so), and it stays unknown. The voxel at the middle of
    the image, (0.025, 0.025, 0.325), whose footprint's rays all pass to the wall, is free."""
    edge, middle = np.array([[0.325, 0.025, 0.325]]), np.array([[0.025, 0.025, 0.325]])
    for camera_x, column in ((-0.012, 163.0), (0.012, 157.0)):
        assert 80.0 * (edge[0, 0] - camera_x) / edge[0, 2] + 80.0 == pytest.approx(column, abs=0.1)
        occ = _wall_view(camera_x=camera_x)
        assert occ.state(edge)[0] == UNKNOWN and occ.state(middle)[0] == FREE


def test_rays_carve_only_within_the_free_range_and_surfaces_are_marked_at_any():
    """A voxel 2.5 m out on the optical axis, 0.5 m before the wall: free when rays may carve to any
    range, unknown within a 2 m free range; the wall's voxels at 3 m are occupied either way."""
    far, wall = np.array([[0.0, 0.0, 2.5]]), np.array([[0.0, 0.0, 3.0 + H / 2]])
    unlimited, limited = _wall_view(), _wall_view(free_range=2.0)
    assert unlimited.state(far)[0] == FREE and limited.state(far)[0] == UNKNOWN
    assert unlimited.state(wall)[0] == OCCUPIED and limited.state(wall)[0] == OCCUPIED
    assert limited.state(np.array([[0.0, 0.0, 1.5]]))[0] == FREE
