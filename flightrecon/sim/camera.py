"""Offscreen RGB-D camera on a MuJoCo world: color and metric z-depth at any OpenCV pose.

One render pass per frame yields both images; the depth buffer is linearized in float64. Poses are camera-to-world in the OpenCV convention; all conversions
to MuJoCo's camera axes go through `geometry`. EGL is selected by `import flightrecon`.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from flightrecon.geometry import intrinsics, mujoco_camera_to_opencv, opencv_to_mujoco_rotation, vfov_deg
from flightrecon.sim.world import ATLAS_TEXTURE, RENDER_CAMERA, World

def _limit_atlas_mipmaps(world: World, ctx: mujoco.MjrContext) -> None:
    """Stop the scene atlas's mip chain where levels would average unrelated faces (scene.bake)."""
    from OpenGL import GL

    tex_id = world.model.texture(ATLAS_TEXTURE).id
    GL.glBindTexture(GL.GL_TEXTURE_2D, int(ctx.texture[tex_id]))
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, int(world.baked.atlas.max_mip_level))
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)


_OFF_FLAGS = ("mjRND_SHADOW", "mjRND_REFLECTION", "mjRND_SKYBOX", "mjRND_FOG", "mjRND_HAZE")


def reduction_for_width(width: int, height: int, max_width: int) -> int:
    """The smallest whole factor dividing both sides that brings `width` to at most `max_width`; the
    largest common one where none does; 1 for max_width 0 (no reduction)."""
    if max_width <= 0 or width <= max_width:
        return 1
    common = [n for n in range(1, math.gcd(width, height) + 1) if width % n == 0 and height % n == 0]
    return next((n for n in common if width // n <= max_width), common[-1])


class RGBDCamera:
    """Pinhole RGB-D sensor: `render(T_wc)` for any pose, `render_named(name)` for a model camera.

    Depth is z-depth in meters along the optical axis, 0 where nothing is hit within `far`.
    Each render sets the world's clip planes to this camera's `near`/`far`.
    """

    def __init__(self, world: World, width: int = 640, height: int = 480, hfov_deg: float = 90.0,
                 near: float = 0.05, far: float = 10.0) -> None:
        if not (width > 0 and height > 0 and 0 < hfov_deg < 180 and 0 < near < far):
            raise ValueError(f"bad camera: {width}x{height}, hfov {hfov_deg}, near {near}, far {far}")
        self.world = world
        self.width, self.height = int(width), int(height)
        self.hfov_deg = float(hfov_deg)
        self.vfov_deg = vfov_deg(width, height, hfov_deg)
        self.near, self.far = float(near), float(far)
        self.K = intrinsics(width, height, hfov_deg)
        m = world.model
        self._cam_id = m.camera(RENDER_CAMERA).id
        m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), self.width)
        m.vis.global_.offheight = max(int(m.vis.global_.offheight), self.height)
        extent = float(m.stat.extent)
        self._clip = (self.near / extent, 2.0 * self.far / extent)  # hits up to `far` are kept
        self._gl = mujoco.GLContext(m.vis.global_.offwidth, m.vis.global_.offheight)
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        _limit_atlas_mipmaps(world, self._ctx)
        self._scene = mujoco.MjvScene(m, maxgeom=max(1000, 2 * m.ngeom))
        for flag in _OFF_FLAGS:
            self._scene.flags[getattr(mujoco.mjtRndFlag, flag)] = 0
        self._opt = mujoco.MjvOption()
        self._vcam = mujoco.MjvCamera()
        self._vcam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), np.uint8)
        self._depth = np.empty((self.height, self.width), np.float32)

    def render(self, T_wc: np.ndarray, reduce: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(rgb (H,W,3) float32 in [0,1], depth (H,W) float32 m) seen from the OpenCV pose T_wc; with
        `reduce` n > 1 the images are 1/n of the sensor's width and height, same field of view
        (intrinsics `intrinsics_at(n)`)."""
        T_wc = np.asarray(T_wc, float)
        m, d = self.world.model, self.world.data
        d.cam_xpos[self._cam_id] = T_wc[:3, 3]
        d.cam_xmat[self._cam_id] = opencv_to_mujoco_rotation(T_wc[:3, :3]).ravel()
        m.cam_fovy[self._cam_id] = self.vfov_deg
        return self._draw(self._cam_id, reduce)

    def render_named(self, camera_name: str, reduce: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render a camera of the model (e.g. the drone's) at its current pose: (rgb, depth, T_wc), at
        1/`reduce` of the sensor's size as in `render`.

        The model camera must have this sensor's field of view, so that `K` describes the image."""
        m, d = self.world.model, self.world.data
        try:
            cam_id = m.camera(camera_name).id
        except KeyError:
            raise ValueError(f"the world has no camera named '{camera_name}'") from None
        if abs(float(m.cam_fovy[cam_id]) - self.vfov_deg) > 1e-4:
            raise ValueError(f"camera '{camera_name}' has a vertical FOV of {float(m.cam_fovy[cam_id]):.4f} deg, "
                             f"this sensor {self.vfov_deg:.4f} deg: build it from the same camera config")
        T_wc = mujoco_camera_to_opencv(d.cam_xpos[cam_id], d.cam_xmat[cam_id])
        rgb, depth = self._draw(cam_id, reduce)
        return rgb, depth, T_wc

    def intrinsics_at(self, reduce: int) -> np.ndarray:
        """K of the images `render(..., reduce)` returns."""
        return intrinsics(*self._reduced_size(reduce), self.hfov_deg)

    def _reduced_size(self, reduce: int) -> tuple[int, int]:
        n = int(reduce)
        if n != reduce or n < 1 or self.width % n or self.height % n:
            raise ValueError(f"cannot reduce a {self.width}x{self.height} image by {reduce}: the factor must be a "
                             f"whole number >= 1 dividing both sides")
        return self.width // n, self.height // n

    def _draw(self, cam_id: int, reduce: int = 1) -> tuple[np.ndarray, np.ndarray]:
        m, d = self.world.model, self.world.data
        w, h = self._reduced_size(reduce)
        # the viewport's corner of the offscreen buffer: the projection keeps the camera's fovy and
        # the viewport's aspect, which a whole factor leaves unchanged
        rect, rgb, depth = ((self._rect, self._rgb, self._depth) if (w, h) == (self.width, self.height) else
                            (mujoco.MjrRect(0, 0, w, h), np.empty((h, w, 3), np.uint8), np.empty((h, w), np.float32)))
        self._gl.make_current()
        m.vis.map.znear, m.vis.map.zfar = self._clip  # the model is shared with other cameras
        self._vcam.fixedcamid = cam_id
        mujoco.mjv_updateScene(m, d, self._opt, None, self._vcam, mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        mujoco.mjr_render(rect, self._scene, self._ctx)
        mujoco.mjr_readPixels(rgb, depth, rect, self._ctx)
        return np.flipud(rgb).astype(np.float32) * np.float32(1.0 / 255.0), self._linear_depth(np.flipud(depth))

    def _linear_depth(self, z: np.ndarray) -> np.ndarray:
        """Metric z-depth from the [0, 1] window depth of MuJoCo's perspective projection."""
        m = self.world.model
        extent = float(m.stat.extent)
        zn = float(np.float32(m.vis.map.znear * extent))
        zf = float(np.float32(m.vis.map.zfar * extent))
        ndc = 2.0 * z.astype(np.float64) - 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (2.0 * zf * zn / ((zf + zn) - ndc * (zf - zn))).astype(np.float32)
        depth[~np.isfinite(depth) | (depth > self.far) | (z >= 1.0)] = 0.0
        return depth

    def close(self) -> None:
        """Free the GL resources now (they are also freed when the object is collected)."""
        if getattr(self, "_ctx", None) is not None:
            self._gl.make_current()
            self._ctx.free()
            self._ctx = None
            self._gl.free()
            self._gl = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
