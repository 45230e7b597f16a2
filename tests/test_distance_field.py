"""DistanceField against independent oracles: trimesh proximity for meshes, closed-form for voxels."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from flightrecon.planning.distance_field import DistanceField, grid_for_bounds

H = 0.05


def _room_with_obstacles() -> tuple[trimesh.Trimesh, list[trimesh.Trimesh]]:
    room = trimesh.creation.box(extents=[6.0, 5.0, 3.0])
    room.apply_translation([0.0, 0.0, 1.5])
    room.invert()  # normals inward: a closed room seen from inside
    box = trimesh.creation.box(extents=[1.0, 0.7, 1.2])
    box.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0, 0, 1]))
    box.apply_translation([1.0, 0.5, 0.6])
    ball = trimesh.creation.icosphere(3, radius=0.4)
    ball.apply_translation([-1.5, 1.0, 1.5])
    return trimesh.util.concatenate([room, box, ball]), [box, ball]


@pytest.fixture(scope="module")
def scene():
    mesh, solids = _room_with_obstacles()
    bounds = np.array([[-3.2, -2.7, -0.2], [3.2, 2.7, 3.2]])
    field = DistanceField.from_mesh(mesh, H, bounds, free_seeds=np.array([[-2.0, -2.0, 1.5]]))
    return mesh, solids, field


def test_mesh_field_matches_trimesh_proximity_within_a_voxel(scene):
    mesh, solids, field = scene
    pts = np.random.default_rng(0).uniform([-2.95, -2.45, 0.05], [2.95, 2.45, 2.95], (4000, 3))
    inside = np.zeros(len(pts), bool)
    for s in solids:
        inside |= s.contains(pts)
    _, true_dist, _ = trimesh.proximity.ProximityQuery(mesh).on_surface(pts)
    err = field.distance(pts)[~inside] - true_dist[~inside]
    assert err.max() <= field.accuracy  # never optimistic by more than a voxel
    assert err.min() >= -1.5 * H  # and not needlessly pessimistic
    assert np.median(np.abs(err)) <= H


def test_inside_closed_obstacles_and_outside_the_grid_read_blocked(scene):
    mesh, solids, field = scene
    assert field.distance(np.array([[1.0, 0.5, 0.6]]))[0] < -0.2  # box center, 0.35 m from its faces
    assert field.distance(np.array([[-1.5, 1.0, 1.5]]))[0] < -0.3  # ball center
    outside = np.array([[5.0, 0.0, 1.0], [0.0, 0.0, 10.0]])
    assert np.all(field.distance(outside) < -1.0)
    assert np.all(field.distance_nearest(outside) < -1.0)


def test_single_voxel_field_is_center_distance_minus_half_voxel():
    origin, shape = grid_for_bounds(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), 0.1)
    blocked = np.zeros(shape, bool)
    blocked[4, 4, 4] = True
    field = DistanceField.from_blocked(blocked, origin, 0.1)
    center = origin + 0.1 * np.array([4.5, 4.5, 4.5])
    ijk = np.array([[0, 0, 0], [7, 4, 4], [9, 1, 3], [4, 4, 4]])
    pts = origin + 0.1 * (ijk + 0.5)
    expect = np.linalg.norm(pts - center, axis=1) - 0.05
    expect[3] = -0.05  # the blocked voxel: half a voxel to its free neighbour's face
    np.testing.assert_allclose(field.distance(pts), expect, atol=1e-6)
    np.testing.assert_allclose(field.distance_nearest(pts + 0.02), expect, atol=1e-6)


def test_gradient_points_away_from_a_wall():
    wall = trimesh.creation.box(extents=[0.1, 4.0, 4.0])  # plane slab at x = 0
    bounds = np.array([[-1.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
    field = DistanceField.from_mesh(wall, H, bounds)
    pts = np.array([[0.6, 0.1, 0.2], [1.0, -0.3, 0.0], [-0.5, 0.5, 0.5]])
    g = field.gradient(pts)
    np.testing.assert_allclose(g, [[1, 0, 0], [1, 0, 0], [-1, 0, 0]], atol=0.05)
    _, true_dist, _ = trimesh.proximity.ProximityQuery(wall).on_surface(pts)
    assert np.all(np.abs(field.distance(pts) - true_dist) <= H + 1e-6)


def test_empty_grid_reads_distance_to_its_box():
    origin, shape = grid_for_bounds(np.array([[0.0, 0.0, 0.0], [2.0, 2.0, 2.0]]), 0.1)
    field = DistanceField.from_blocked(np.zeros(shape, bool), origin, 0.1)
    np.testing.assert_allclose(field.distance(np.array([[1.0, 1.0, 1.0], [0.25, 1.0, 1.0]])),
                               [0.95, 0.25], atol=0.051)
