"""A person scanning a room with a hand-held RGB-D sensor: their walk, and the depth and colour the
sensor records, rendered by ray casting the scene's triangles.

Real reconstructions (ScanNet, BundleFusion, KinectFusion) are fused from such recordings, so their
flaws come from here: the camera stays at chest to eye height and rarely looks up, so the ceiling
is seen obliquely or not at all; the depth is noisy with a noise that grows with the square of the
distance (Kinect's structured light: the axial noise model of Nguyen, Izadi and Lovell 2012), has
no return beyond its range, at grazing angles and on depth edges, and loses random pixels. Rendering is exact (Open3D's
RaycastingScene, an Embree BVH), so every flaw is one of those added on purpose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flightrecon.geometry import camera_pose, intrinsics, make_pose, pixel_rays, rot_z
from flightrecon.open3d_import import open3d_module
from flightrecon.scene.surface_distance import SurfaceDistance


@dataclass(frozen=True)
class Sensor:
    """A Kinect-like RGB-D sensor: image size, field of view, range and how its depth fails."""

    width: int = 160
    height: int = 120
    hfov_deg: float = 65.0
    min_depth: float = 0.4  # m: closer surfaces return nothing
    max_depth: float = 4.5  # m: farther surfaces return nothing
    dropout: float = 0.02  # share of pixels lost at random
    grazing_deg: float = 78.0  # surfaces seen more obliquely than this return nothing
    edge_jump: float = 0.08  # relative depth step to a neighbour that drops a pixel (flying pixels)

    @property
    def K(self) -> np.ndarray:
        return intrinsics(self.width, self.height, self.hfov_deg)

    def noise_sigma(self, z: np.ndarray) -> np.ndarray:
        """Standard deviation (m) of the depth noise at depth z (m)."""
        return 0.0012 + 0.0019 * (z - 0.4) ** 2


def handheld_walk(center: np.ndarray, half_extent: np.ndarray, frames: int, rng: np.random.Generator, *,
                  look_up: bool) -> np.ndarray:
    """T_wc (frames, 4, 4) of one loop around `center` (x, y, floor z) inside a room of horizontal
    `half_extent`: the sensor held 1.2-1.7 m high, turning twice around while walking, pitched down
    (and, with `look_up`, up toward the ceiling too), with the small roll and shake of a hand. It
    starts looking down most steeply, so a scan stored in its first camera's frame is well tilted."""
    t = np.arange(frames) / frames
    radius = np.clip(0.35 * np.asarray(half_extent, float)[:2], 0.6, 1.8)
    phase = rng.uniform(0, 2 * math.pi, 4)
    theta = 2 * math.pi * t + phase[0]
    xy = np.asarray(center, float)[:2] + radius * np.stack([np.cos(theta), np.sin(theta)], 1)
    xy += rng.normal(0, 0.03, xy.shape)
    z = center[2] + 1.45 + 0.2 * np.sin(4 * math.pi * t + phase[1]) + rng.normal(0, 0.01, frames)
    yaw = 4 * math.pi * t + phase[2] + rng.normal(0, math.radians(1.5), frames)
    mean, swing = (5.0, 45.0) if look_up else (15.0, 15.0)  # degrees, positive looks down
    pitch = mean + swing * np.cos(6 * math.pi * t) + rng.normal(0, 1.5, frames)
    roll = 3.0 * np.sin(2 * math.pi * t + phase[3]) + rng.normal(0, 1.0, frames)
    poses = []
    for k in range(frames):
        T = camera_pose(np.array([xy[k, 0], xy[k, 1], z[k]]), yaw[k], pitch[k])
        poses.append(T @ make_pose(rot_z(math.radians(roll[k])), np.zeros(3)))  # roll about the optical axis
    return np.stack(poses)


class RaycastCamera:
    """Exact depth and colour of a mesh with vertex colours, seen by a `Sensor` at poses T_wc."""

    def __init__(self, mesh, vertex_colors: np.ndarray, sensor: Sensor) -> None:
        """`mesh`: anything with vertices and faces (a Scene, a trimesh)."""
        self.surface = SurfaceDistance(mesh)  # one BVH for the rays and for clearance
        self.faces = np.asarray(mesh.faces, np.int64)
        self.colors = np.asarray(vertex_colors, np.float64) / 255.0
        self.sensor = sensor
        self._rays = pixel_rays(sensor.width, sensor.height, sensor.K).reshape(-1, 3)  # z = 1: t is z-depth

    def render(self, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z-depth (H, W), 0 where nothing is hit; RGB (H, W, 3) in [0, 1]; cosine of the angle
        between each ray and the surface normal (H, W))."""
        o3d = open3d_module()
        dirs = self._rays @ T_wc[:3, :3].T
        rays = np.concatenate([np.broadcast_to(T_wc[:3, 3], dirs.shape), dirs], 1).astype(np.float32)
        hit = self.surface.raycasting_scene().cast_rays(o3d.core.Tensor(rays))
        depth = hit["t_hit"].numpy().astype(np.float64)
        ok = np.isfinite(depth)
        ids = np.where(ok, hit["primitive_ids"].numpy(), 0).astype(np.int64)
        uv = hit["primitive_uvs"].numpy().astype(np.float64)
        bary = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)  # hit = sum w_i v_i
        rgb = np.einsum("nk,nkc->nc", bary, self.colors[self.faces[ids]]) * ok[:, None]
        normal = hit["primitive_normals"].numpy().astype(np.float64)
        cos = np.abs(np.einsum("nc,nc->n", normal, dirs)) / np.linalg.norm(dirs, axis=1)
        shape = (self.sensor.height, self.sensor.width)
        return np.where(ok, depth, 0.0).reshape(shape), rgb.reshape(shape + (3,)), np.where(ok, cos, 0.0).reshape(shape)

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance (m) from each point (N, 3) to the nearest triangle (the same BVH the rays use)."""
        return self.surface.distance(points)


def sensor_depth(depth: np.ndarray, cos: np.ndarray, sensor: Sensor, rng: np.random.Generator) -> np.ndarray:
    """What the sensor measures of the exact z-depth: out of range, grazing, depth-edge and random
    pixels lost (0), the rest with depth-dependent Gaussian noise."""
    z = np.asarray(depth, float)
    lost = (z < sensor.min_depth) | (z > sensor.max_depth) | (cos < math.cos(math.radians(sensor.grazing_deg)))
    padded = np.pad(z, 1, mode="edge")
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        lost |= np.abs(padded[dy:dy + z.shape[0], dx:dx + z.shape[1]] - z) > sensor.edge_jump * np.maximum(z, 1e-6)
    lost |= rng.random(z.shape) < sensor.dropout
    noisy = z + rng.normal(0.0, 1.0, z.shape) * sensor.noise_sigma(z)
    return np.where(lost, 0.0, noisy)
