"""Poses, intrinsics and frame conventions: the one place where frames are converted.

Conventions (docs/architecture.md, "Conventions"):
- World: z up, meters, radians. Body (drone): x forward, y left, z up.
- Camera, for all vision math: OpenCV (x right, y down, z forward). MuJoCo cameras look along -z
  with y up; `R_CV_FROM_MJ` converts.
- Poses are camera-to-world 4x4 (`T_wc`); view matrices (world-to-camera) are their inverses.
- Continuous pixel coordinates: pixel (i, j) covers [i, i+1) x [j, j+1), its center is at
  (i + 0.5, j + 0.5); so cx = width / 2 for a centered principal point (gsplat's convention).
- Quaternions are (w, x, y, z), MuJoCo's and gsplat's order.
"""

from __future__ import annotations

import math

import numpy as np

# MuJoCo camera axes (x right, y up, -z forward) -> OpenCV axes (x right, y down, z forward).
R_CV_FROM_MJ = np.diag([1.0, -1.0, -1.0])

# Camera axes expressed in the body frame for a level, forward-looking camera:
# camera x = -body y, camera y = -body z, camera z = body x.
R_BODY_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K with square pixels from the horizontal field of view (paper: 640x480, 90 deg -> f=320)."""
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def vfov_deg(width: int, height: int, hfov_deg: float) -> float:
    """Vertical field of view for square pixels (MuJoCo cameras are specified by it)."""
    return math.degrees(2.0 * math.atan(math.tan(math.radians(hfov_deg) / 2.0) * height / width))


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (batched over leading dims)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def body_to_camera_rotation(pitch_deg: float = 0.0) -> np.ndarray:
    """Rotation of the OpenCV camera in the body frame; positive pitch tilts the view down."""
    return rot_y(math.radians(pitch_deg)) @ R_BODY_CAM_LEVEL


def camera_pose(position: np.ndarray, yaw: float, pitch_deg: float = 0.0) -> np.ndarray:
    """T_wc of a camera at `position` on a level body with heading `yaw` (viewpoints have no roll)."""
    return make_pose(rot_z(yaw) @ body_to_camera_rotation(pitch_deg), np.asarray(position, float))


def camera_pose_from_body(T_wb: np.ndarray, cam_offset: np.ndarray, pitch_deg: float = 0.0) -> np.ndarray:
    """T_wc from the body pose and the camera's mounting point (body frame)."""
    T_bc = make_pose(body_to_camera_rotation(pitch_deg), np.asarray(cam_offset, float))
    return T_wb @ T_bc


def mujoco_camera_to_opencv(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """T_wc (OpenCV) from a MuJoCo camera's world position and 3x3 orientation (data.cam_xpos/xmat)."""
    return make_pose(np.asarray(xmat, float).reshape(3, 3) @ R_CV_FROM_MJ, xpos)


def opencv_to_mujoco_rotation(R_wc: np.ndarray) -> np.ndarray:
    """World orientation of a MuJoCo camera that sees what the OpenCV camera R_wc sees."""
    return R_wc @ R_CV_FROM_MJ


def opencv_to_opengl_pose(T_wc: np.ndarray) -> np.ndarray:
    """Camera-to-world in OpenGL/nerfstudio axes (x right, y up, z back) from OpenCV axes.

    nerfstudio's `transforms.json` stores OpenGL-convention poses; this is its own inverse."""
    out = np.array(T_wc, float, copy=True)
    out[..., :3, 1:3] *= -1.0
    return out


opengl_to_opencv_pose = opencv_to_opengl_pose


def yaw_of_camera(T_wc: np.ndarray) -> float:
    """Heading of the camera's optical axis projected onto the ground plane."""
    z = T_wc[:3, 2]
    return math.atan2(z[1], z[0])


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(w, x, y, z) -> 3x3, batched over leading dims; q need not be normalized."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1)
    return R.reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """3x3 -> (w, x, y, z) with w >= 0, batched; numerically safe branch per element."""
    R = np.asarray(R, float)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for n, m in enumerate(flat):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        if tr > 0:
            s = math.sqrt(tr + 1.0) * 2
            q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
            q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif m[1, 1] > m[2, 2]:
            s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
            q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
            q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        q = np.array(q)
        out[n] = q if q[0] >= 0 else -q
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out.reshape(R.shape[:-2] + (4,))


def pixel_rays(width: int, height: int, K: np.ndarray) -> np.ndarray:
    """Camera-frame directions (z = 1) through every pixel center, shape (H, W, 3)."""
    u = np.arange(width) + 0.5
    v = np.arange(height) + 0.5
    uu, vv = np.meshgrid(u, v)
    x = (uu - K[0, 2]) / K[0, 0]
    y = (vv - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def backproject_depth(depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points of the valid (finite, > 0) z-depth pixels, and the (H, W) validity mask."""
    depth = np.asarray(depth, float)
    valid = np.isfinite(depth) & (depth > 0)
    rays = pixel_rays(depth.shape[1], depth.shape[0], K)
    pts_c = rays[valid] * depth[valid][:, None]
    pts_w = pts_c @ T_wc[:3, :3].T + T_wc[:3, 3]
    return pts_w, valid


def project_points(points_w: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel coordinates (N, 2) and camera z-depth (N,) of world points."""
    T_cw = invert_pose(T_wc)
    pc = np.asarray(points_w, float) @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([K[0, 0] * pc[:, 0] / z + K[0, 2], K[1, 1] * pc[:, 1] / z + K[1, 2]], axis=1)
    return uv, z
