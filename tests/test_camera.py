"""RGB-D camera: exact z-depth on planes, unlit colors, pixel convention, depth on the mesh, drone cam."""

from __future__ import annotations

import flightrecon  # noqa: F401  (selects EGL before mujoco loads)

import math

import numpy as np
import pytest

from flightrecon.geometry import (backproject_depth, camera_pose, invert_pose, project_points, rot_y,
                                  rot_z)
from flightrecon.scenario import load_config
from flightrecon.scene.builder import QuadMeshBuilder
from flightrecon.scene.patterns import solid
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import quads_to_triangles
from flightrecon.scene.types import Scene
from flightrecon.sim.camera import RGBDCamera, reduction_for_width
from flightrecon.sim.world import build_world

GRAY = (0.25, 0.5, 0.75)


def _scene(build) -> Scene:
    b = QuadMeshBuilder()
    build(b, np.random.default_rng(0))
    v, c, n, q = b.build()
    return Scene("test", v.astype(np.float64), quads_to_triangles(q), vertex_colors=c, meta={"quad_faces": True})


def _square(b, center, normal, size, color, rng, cell=0.5):
    """A square facing along `normal` (its front face points that way)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross([0.0, 0.0, 1.0], n)
    u = u / np.linalg.norm(u) * size
    v = np.cross(n, u)
    b.plane(np.asarray(center) - (u + v) / 2, u, v, cell, solid(color, rng, variation=0.0))


def _world(tmp_path, scene, collision_voxel=0.05):
    # large sloped test planes voxelize into many small boxes: collision is not under test here
    cfg = load_config(None, [f'scene.cache_dir="{tmp_path}"', f"scene.collision_voxel={collision_voxel}"])
    return build_world(scene, cfg, with_drone=False)


PLANE_P0 = np.array([2.0, 0.0, 0.3])
PLANE_N = rot_z(math.radians(30)) @ rot_y(math.radians(-20)) @ np.array([-1.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def plane_world(tmp_path_factory):
    scene = _scene(lambda b, rng: _square(b, PLANE_P0, PLANE_N, 30.0, GRAY, rng, cell=1.0))
    return _world(tmp_path_factory.mktemp("plane"), scene, collision_voxel=1.0)


def _plane_depth(cam: RGBDCamera, T: np.ndarray) -> np.ndarray:
    """Analytic z-depth: points z * (x, y, 1) on the plane n_c . X = h_c in the camera frame."""
    T_cw = invert_pose(T)
    n_c = T_cw[:3, :3] @ PLANE_N
    h_c = n_c @ (T_cw[:3, :3] @ PLANE_P0 + T_cw[:3, 3])
    u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    rays = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(u)], -1)
    return h_c / (rays @ n_c)


def test_depth_of_a_tilted_plane_is_exact_to_a_millimeter(plane_world):
    cam = RGBDCamera(plane_world, 320, 240, 90.0, 0.05, 20.0)
    T = camera_pose([0.0, 0.1, 0.2], yaw=0.15, pitch_deg=8.0)
    _, depth = cam.render(T)
    expected = _plane_depth(cam, T)
    assert (depth > 0).all()
    assert np.abs(depth - expected).max() < 1e-3
    assert expected.max() - expected.min() > 1.0  # the plane is really seen at an angle


@pytest.mark.parametrize("reduce", [2, 4])
def test_a_reduced_render_is_the_smaller_camera_exact_to_a_millimeter(plane_world, reduce):
    cam = RGBDCamera(plane_world, 320, 240, 90.0, 0.05, 20.0)
    T = camera_pose([0.0, 0.1, 0.2], yaw=0.15, pitch_deg=8.0)
    _, depth = cam.render(T, reduce)
    small = RGBDCamera(plane_world, 320 // reduce, 240 // reduce, 90.0, 0.05, 20.0)
    np.testing.assert_array_equal(cam.intrinsics_at(reduce), small.K)
    assert depth.shape == (240 // reduce, 320 // reduce)
    assert np.abs(depth - _plane_depth(small, T)).max() < 1e-3
    _, full = cam.render(T)  # the full size is drawn whole after a reduced one
    assert np.abs(full - _plane_depth(cam, T)).max() < 1e-3


@pytest.mark.parametrize("reduce", [0, 3, 1.5])
def test_a_factor_that_does_not_divide_the_image_is_refused(plane_world, reduce):
    cam = RGBDCamera(plane_world, 320, 240, 90.0, 0.05, 20.0)
    with pytest.raises(ValueError, match=f"cannot reduce a 320x240 image by {reduce}"):
        cam.render(camera_pose([0.0, 0.0, 0.3], yaw=0.0), reduce)


@pytest.mark.parametrize("size, max_width, factor", [
    ((320, 240), 160, 2), ((640, 480), 160, 4), ((160, 120), 160, 1), ((80, 60), 160, 1),
    ((300, 225), 160, 3),  # common divisors 1, 3, 5, 15, 25, 75: 300 / 3 = 100 is the first <= 160
    ((322, 241), 160, 1),  # coprime sides: nothing divides both
    ((330, 240), 50, 10),  # common 1, 2, 3, 5, 6, 10, 15, 30: 330 / 6 = 55, 330 / 10 = 33
    ((322, 240), 50, 2),  # common 1, 2: none brings 322 to 50, so the largest
    ((640, 480), 0, 1)])
def test_the_reduction_for_a_width_divides_both_sides(size, max_width, factor):
    assert reduction_for_width(*size, max_width) == factor


def test_unlit_color_equals_the_mesh_color(plane_world):
    cam = RGBDCamera(plane_world, 160, 120, 90.0, 0.05, 20.0)
    rgb, depth = cam.render(camera_pose([0.0, 0.0, 0.3], yaw=0.0))
    expected = np.round(np.array(GRAY) * 255) / 255
    assert (depth > 0).mean() > 0.9
    assert np.abs(rgb[depth > 0] - expected).max() <= 1.5 / 255
    assert (rgb[depth == 0] == 0).all()  # no background color where nothing is hit


def test_depth_is_zero_without_a_hit_or_beyond_far(plane_world):
    cam = RGBDCamera(plane_world, 160, 120, 90.0, 0.05, 20.0)
    rgb, depth = cam.render(camera_pose([0.0, 0.0, 0.3], yaw=math.pi))  # looking away from the plane
    assert (depth == 0).all()
    short = RGBDCamera(plane_world, 160, 120, 90.0, 0.05, 2.0)
    T = camera_pose([0.0, 0.0, 0.3], yaw=0.0)
    _, depth = short.render(T)
    expected = _plane_depth(short, T)
    beyond = expected > 2.0 + 1e-3
    assert beyond.mean() > 0.2 and (~beyond).mean() > 0.2  # the plane crosses the far range
    assert (depth[beyond] == 0).all()
    within = expected < 2.0 - 1e-3
    assert np.abs(depth[within] - expected[within]).max() < 1e-3
    _, depth = cam.render(T)  # the first camera keeps its own far range on the shared world
    mid = beyond & (expected < 5.0)
    assert mid.sum() > 100 and np.abs(depth[mid] - expected[mid]).max() < 1e-3


def test_known_point_projects_to_the_pixel_where_it_is_rendered(tmp_path):
    target = np.array([2.0, 0.6, 0.45])  # left of and above the optical axis
    origin = np.array([0.0, 0.0, 0.0])

    def build(b, rng):
        _square(b, [4.0, 0.0, 0.0], [-1, 0, 0], 12.0, GRAY, rng, cell=2.0)
        _square(b, target, origin - target, 0.08, (1.0, 0.0, 0.0), rng, cell=0.04)

    world = _world(tmp_path, _scene(build), collision_voxel=0.5)
    cam = RGBDCamera(world, 640, 480, 90.0, 0.05, 20.0)
    T = camera_pose(origin, yaw=0.1, pitch_deg=-4.0)
    rgb, depth = cam.render(T)
    red = (rgb[..., 0] > 0.9) & (rgb[..., 1] < 0.1)
    vs, us = np.nonzero(red)
    centroid = np.array([us.mean() + 0.5, vs.mean() + 0.5])  # pixel centers are at +0.5
    uv, z = project_points(target[None], cam.K, T)
    assert red.sum() > 80
    assert np.linalg.norm(centroid - uv[0]) < 0.5
    assert uv[0, 0] < 320 and uv[0, 1] < 240  # left and up, as in the world
    assert abs(depth[int(uv[0, 1]), int(uv[0, 0])] - z[0]) < 1e-3


@pytest.mark.slow
def test_backprojected_depth_lands_on_the_mesh(tmp_path):
    import trimesh

    scene = make_scene("room0")
    cam = RGBDCamera(_world(tmp_path, scene), 320, 240, 90.0, 0.05, 10.0)
    T = camera_pose([0.3, -0.2, 1.1], yaw=2.2, pitch_deg=25.0)
    _, depth = cam.render(T)
    pts, valid = backproject_depth(depth, cam.K, T)
    assert valid.all()
    sample = pts[np.random.default_rng(0).choice(len(pts), 3000, replace=False)]
    _, dist, _ = trimesh.proximity.closest_point(scene.trimesh, sample)
    assert dist.mean() < 0.005
    assert np.median(dist) < 0.001


@pytest.mark.slow
@pytest.mark.parametrize("name", ["office0", "room1"])
def test_depth_has_no_holes_in_any_direction(tmp_path, name):
    """Looking along +-x, +-y, up and down from the take-off column: the room is closed."""
    scene = make_scene(name)
    cam = RGBDCamera(_world(tmp_path, scene), 160, 160, 90.0, 0.05, 20.0)
    lo, hi = np.asarray(scene.meta["free_box"])
    for p in (0.5 * (lo + hi), lo + 0.1, hi - 0.1):
        for yaw, pitch in [(0, 0), (math.pi / 2, 0), (math.pi, 0), (-math.pi / 2, 0), (0, 89.9), (0, -89.9)]:
            _, depth = cam.render(camera_pose(p, yaw, pitch))
            assert (depth > 0).all(), (p, yaw, pitch)


def test_render_named_drone_camera_matches_pose_render(tmp_path):
    pytest.importorskip("flightrecon.sim.quadrotor")
    from flightrecon.geometry import camera_pose_from_body, make_pose
    from flightrecon.sim.quadrotor import DroneHandle, camera_offset

    cfg = load_config(None, [f'scene.cache_dir="{tmp_path}"', "camera.width=160", "camera.height=120"])
    def room(b, rng):  # the six inward faces of a 6 m cube with a smooth color pattern
        app = lambda s, t: np.stack([0.5 + 0.5 * np.sin(7 * s), 0.5 + 0.5 * np.cos(5 * t), 0.4 + 0 * s], 1)
        for axis in range(3):
            for sign in (-1.0, 1.0):
                n = np.zeros(3)
                n[axis] = -sign  # pointing into the cube
                u = np.zeros(3)
                u[(axis + 1) % 3] = 6.0
                v = np.cross(n, u) / 6.0 * 6.0
                center = np.array([0.0, 0.0, 1.5])
                center[axis] += sign * 3.0
                b.plane(center - (u + v) / 2, u, v, 0.25, app)

    scene = _scene(room)
    world = build_world(scene, cfg, with_drone=True)
    cam = RGBDCamera(world, cfg.camera.width, cfg.camera.height, cfg.camera.hfov_deg, cfg.camera.near,
                     cfg.camera.far)
    handle = DroneHandle(world.model)
    import mujoco

    world.data.qpos[handle.qpos_adr:handle.qpos_adr + 7] = [0.3, -0.2, 1.0, math.cos(0.3), 0, 0, math.sin(0.3)]
    mujoco.mj_forward(world.model, world.data)
    rgb, depth, T = cam.render_named("drone_cam")
    st = handle.state(world.data)
    T_expected = camera_pose_from_body(make_pose(st.R, st.position), camera_offset(cfg.drone.arm_length),
                                       cfg.camera.pitch_deg)
    np.testing.assert_allclose(T, T_expected, atol=1e-9)
    rgb2, depth2 = cam.render(T)
    np.testing.assert_allclose(rgb, rgb2, atol=1 / 255)
    np.testing.assert_allclose(depth, depth2, atol=1e-5)
    # the box's inside is closed around the drone: every pixel sees a wall
    assert (depth > 0).all()


def test_uv_textured_obj_renders_with_its_texture_the_right_way_up(tmp_path):
    from test_scene_loaders import _write_textured_obj

    from flightrecon.scene import load_scene

    _write_textured_obj(tmp_path)  # unit quad in z = 0: red top-left, green top-right, blue, white
    world = _world(tmp_path, load_scene(tmp_path / "quad.obj"))
    cam = RGBDCamera(world, 160, 120, 90.0, 0.05, 10.0)
    T = camera_pose([0.5, 0.5, 1.0], yaw=0.7, pitch_deg=89.0)  # looking down, turned
    rgb, _ = cam.render(T)
    quadrants = {(0.25, 0.75): (1, 0, 0), (0.75, 0.75): (0, 1, 0), (0.25, 0.25): (0, 0, 1), (0.75, 0.25): (1, 1, 1)}
    for (x, y), color in quadrants.items():
        uv, _ = project_points(np.array([[x, y, 0.0]]), cam.K, T)
        np.testing.assert_allclose(rgb[int(uv[0, 1]), int(uv[0, 0])], color, atol=0.05)  # mip blend
