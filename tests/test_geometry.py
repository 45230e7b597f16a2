"""Frame conventions: intrinsics, camera axes, quaternions, projection and back-projection."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from flightrecon import geometry as g


def test_paper_intrinsics():
    K = g.intrinsics(640, 480, 90.0)
    assert K[0, 0] == pytest.approx(320.0) and K[1, 1] == pytest.approx(320.0)
    assert (K[0, 2], K[1, 2]) == (320.0, 240.0)
    assert g.vfov_deg(640, 480, 90.0) == pytest.approx(math.degrees(2 * math.atan(0.75)))


def test_level_camera_axes_follow_body():
    T = g.camera_pose([1.0, 2.0, 1.5], yaw=math.pi / 2)
    np.testing.assert_allclose(T[:3, 2], [0, 1, 0], atol=1e-12)  # optical axis = heading
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image y = down
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)  # image x = right of heading
    down = g.camera_pose([0, 0, 0], 0.0, pitch_deg=30.0)[:3, 2]
    assert down[2] == pytest.approx(-0.5)


def test_quaternion_round_trip_matches_scipy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    R = g.quat_to_rotmat(q)
    ref = Rotation.from_quat(np.roll(q, -1, axis=1)).as_matrix()  # scipy is (x, y, z, w)
    np.testing.assert_allclose(R, ref, atol=1e-12)
    q2 = g.rotmat_to_quat(R)
    np.testing.assert_allclose(g.quat_to_rotmat(q2), R, atol=1e-12)


def test_mujoco_and_opengl_conversions_are_consistent():
    R_wc = g.camera_pose([0, 0, 0], 0.3)[:3, :3]
    R_mj = g.opencv_to_mujoco_rotation(R_wc)
    back = g.mujoco_camera_to_opencv(np.zeros(3), R_mj)[:3, :3]
    np.testing.assert_allclose(back, R_wc, atol=1e-12)
    np.testing.assert_allclose(R_mj[:, 2], -R_wc[:, 2])  # MuJoCo looks along -z
    T = g.camera_pose([1, 2, 3], 0.7)
    np.testing.assert_allclose(g.opengl_to_opencv_pose(g.opencv_to_opengl_pose(T)), T)


def test_backproject_then_project_is_identity():
    K = g.intrinsics(64, 48, 90.0)
    T = g.camera_pose([0.5, -1.0, 1.2], 1.0, pitch_deg=10.0)
    depth = np.random.default_rng(1).uniform(0.5, 4.0, size=(48, 64)).astype(np.float32)
    depth[3, 5] = 0.0
    depth[7, 9] = np.nan
    pts, valid = g.backproject_depth(depth, K, T)
    assert valid.sum() == 48 * 64 - 2
    uv, z = g.project_points(pts, K, T)
    vv, uu = np.nonzero(valid)
    np.testing.assert_allclose(uv, np.stack([uu + 0.5, vv + 0.5], 1), atol=1e-6)
    np.testing.assert_allclose(z, depth[valid], rtol=1e-6)
