import flightrecon  # noqa: F401  (selects EGL before mujoco loads)

import pickle

import numpy as np
import pytest
import trimesh

from flightrecon.errors import DataError
from flightrecon.planning.distance_field import DistanceField
from flightrecon.scene.source import procedural_scene
from flightrecon.scene.surface_distance import SurfaceDistance


def test_matches_trimesh_closest_points_on_a_procedural_room():
    scene = procedural_scene("office0", 0)
    lo, hi = scene.trimesh.bounds
    pts = lo + np.random.default_rng(0).random((300, 3)) * (hi - lo)
    _, expected, _ = trimesh.proximity.ProximityQuery(scene.trimesh).on_surface(pts)
    np.testing.assert_allclose(SurfaceDistance(scene.trimesh).distance(pts), expected, atol=1e-5)


def test_is_exact_where_the_voxel_field_is_not():
    """Beside a box's edge the 5 cm field reads low by centimeters; the exact distance is analytic."""
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    t = np.linspace(0.0, 0.5, 51)
    pts = np.stack([0.5 + t, 0.5 + t, np.zeros_like(t)], 1)  # out from the vertical edge at (0.5, 0.5)
    exact = SurfaceDistance(box).distance(pts)
    np.testing.assert_allclose(exact, np.sqrt(2) * t, atol=1e-6)
    field = DistanceField.from_mesh(box, 0.05, np.array([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]]), signed=False)
    assert np.abs(field.distance(pts) - exact).max() > 0.01


def test_edge_values_and_pickling():
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    d = SurfaceDistance(box)
    pts = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [1e30, 0.0, 0.0], [0.5, 0.0, 0.0], [1e-40, 0.0, 0.0]])
    out = d.distance(pts)
    assert out[0] == pytest.approx(0.5) and np.isnan(out[1]) and out[2] > 1e29
    assert out[3] == 0.0 and out[4] == pytest.approx(0.5)
    assert d.distance(np.zeros((0, 3))).shape == (0,)
    copy = pickle.loads(pickle.dumps(d))
    np.testing.assert_array_equal(copy.distance(pts[[0, 3]]), out[[0, 3]])


def test_a_mesh_without_triangles_is_one_clear_error():
    empty = trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), int))
    with pytest.raises(DataError, match="no triangles|none"):
        SurfaceDistance(empty)
