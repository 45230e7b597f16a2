"""Online occupancy voxel map built from depth frames: free along rays, occupied at hits, unknown elsewhere.

Each frame is integrated in projective form, the vectorized equivalent of casting every pixel's ray:
every voxel in the camera's view asks the pixels its footprint covers whether the measured surface
lies more than a voxel behind its center (then the rays passed through it: free), and every valid
depth point marks its voxel as hit.

A hit is final. The scene is static and the depth exact to the renderer, so a voxel that once held
a measured surface point holds surface; a passing ray only proves the line through one pixel empty.
At thin edges and grazing angles (a table top's rim seen from above) the ray through a voxel's
center passes while the surface crosses a corner of the voxel; asking only that ray, and weighing
evidence as OctoMap-style log-odds (hit +0.85, pass -0.4), carved such rims after three passes and
let the planner route the drone's body into them. Spurious hits (from pose noise) therefore stay
as obstacles: the safe side. A pixel without a return (0) carves nothing unless the caller says
it means "nothing within range" (`no_return`: the simulated camera's far plane). Voxels never
touched stay unknown; planning never flies through the unseen: its body keeps clear of unknown
space, and its safety margin keeps clear of occupied space (`distance_field(unknown_offset)`).

What no rule here can catch: a surface that no pixel's ray hits. A thin plate seen almost edge-on
(a lamp's top disc a few centimeters below the camera) can project to less than a pixel row, fall
between pixel centers and leave every ray of its voxels passing. Its projected height shrinks with
range, so rays carve only within `free_range` of the camera (planner.free_range); beyond it space
stays unknown until a nearer view. A voxel whose footprint reaches past the image border is not
carved either: the part outside was not looked at (a table top just below the bottom edge of the
image, a few centimetres from the camera, was carved that way).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from flightrecon.errors import DataError
from flightrecon.geometry import backproject_depth, invert_pose, pixel_rays
from flightrecon.planning.distance_field import DistanceField, grid_for_bounds

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
# half-widths (px) a voxel's footprint is rounded up to; the last caps it (a voxel at the lens covers the image)
FOOTPRINT_PX = np.array([1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64])
RAYS_PER_BLOCK = 4096  # rays cast together by integrate_rays (bounds its sample array)


class OccupancyMap:
    """Voxel grid over a workspace box: surface (ever hit), observed (hit or passed), else unknown;
    `blocked()` is everything not known to be free."""

    def __init__(self, bounds: np.ndarray, voxel_size: float = 0.05, free_range: float = np.inf):
        self.voxel_size = float(voxel_size)
        self.free_range = float(free_range)  # m from the camera within which rays carve (surfaces: any range)
        self.origin, self.shape = grid_for_bounds(bounds, voxel_size)
        self.surface = np.zeros(self.shape, bool)
        self.observed = np.zeros(self.shape, bool)

    @property
    def bounds(self) -> np.ndarray:
        return np.stack([self.origin, self.origin + np.array(self.shape) * self.voxel_size])

    def get_state(self) -> dict:
        """The evidence (copies of the surface and observed grids); the grid's geometry comes from the config."""
        return {"surface": self.surface.copy(), "observed": self.observed.copy()}

    def set_state(self, state: dict) -> None:
        """Continue from a `get_state()` snapshot of a map over the same bounds and voxel size."""
        surface, observed = np.array(state["surface"], bool), np.array(state["observed"], bool)
        if surface.shape != self.shape or observed.shape != self.shape:
            raise ValueError(f"occupancy state of grid {surface.shape} does not fit this map's grid {self.shape}")
        self.surface, self.observed = surface, observed

    def integrate(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, no_return: float = 0.0) -> None:
        """Add one z-depth frame (meters) seen from camera pose T_wc (OpenCV axes).

        A pixel of depth 0 had no return: by default no evidence (a real sensor's dropout on dark or
        glassy surfaces). `no_return` > 0 reads it as no surface up to that depth instead: a simulated
        camera, which returns 0 only where nothing lies within its far plane (a scan's holes, its
        missing ceiling). Non-finite depths are no evidence; a frame of the wrong shape or a
        non-finite pose is a DataError."""
        depth = _checked_frame(depth, K, T_wc)
        h = self.voxel_size
        hit, evidence = self._hits(depth, K, T_wc, no_return)
        max_d = float(min(evidence.max(), self.free_range)) if evidence.size else 0.0
        if max_d <= 0:
            self._apply(hit, None)
            return
        # Voxels in the view frustum up to the farthest measurement, or the free range if nearer
        # (none beyond it is carved).
        H, W = depth.shape
        corners = np.array([[0, 0], [W, 0], [0, H], [W, H]], float)
        rays = np.concatenate([(corners - K[:2, 2]) / np.diag(K)[:2], np.ones((4, 1))], axis=1)
        frustum_c = np.concatenate([np.zeros((1, 3)), rays * max_d], axis=0)
        frustum_w = frustum_c @ T_wc[:3, :3].T + T_wc[:3, 3]
        lo = np.maximum(np.floor((frustum_w.min(0) - self.origin) / h).astype(int), 0)
        hi = np.minimum(np.ceil((frustum_w.max(0) - self.origin) / h).astype(int) + 1, self.shape)
        if np.any(hi <= lo):
            self._apply(hit, None)
            return
        ii, jj, kk = [np.arange(a, b) for a, b in zip(lo, hi)]
        T_cw = invert_pose(T_wc)
        R, t = T_cw[:3, :3], T_cw[:3, 3]
        # Camera coordinates of all voxel centers of the box, built separably (no (N, 3) world array).
        cx = self.origin[0] + (ii + 0.5) * h
        cy = self.origin[1] + (jj + 0.5) * h
        cz = self.origin[2] + (kk + 0.5) * h
        pc = (R[:, 0, None, None, None] * cx[None, :, None, None] + R[:, 1, None, None, None] * cy[None, None, :, None]
              + R[:, 2, None, None, None] * cz[None, None, None, :] + t[:, None, None, None]).astype(np.float32)
        z = pc[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * pc[0] / z + K[0, 2]
            v = K[1, 1] * pc[1] / z + K[1, 2]
        in_view = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        sel = np.nonzero(in_view)
        ui = np.clip(u[sel], 0, W - 1).astype(np.int64)
        vi = np.clip(v[sel], 0, H - 1).astype(np.int64)
        zs = z[sel]
        # The rays passed this voxel if every pixel its footprint covers measured a surface more than
        # a voxel behind its center: the pixel at its center alone misses a rim crossing its corner.
        # A footprint that leaves the image has no evidence for its outer part: nothing is carved.
        # Half-widths rounded up to a few sizes (a wider square is the safe side): one filter per size.
        radius = footprint_px(h, K[0, 0], zs)
        d = _footprint_min_depth(evidence, ui, vi, radius)
        passed = (d > 0) & (zs < d - h) & (zs <= self.free_range)
        free = np.zeros(self.shape, bool)
        free[sel[0][passed] + lo[0], sel[1][passed] + lo[1], sel[2][passed] + lo[2]] = True
        self._apply(hit, free)

    def integrate_rays(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, no_return: float = 0.0,
                       max_width: int = 160) -> None:
        """`integrate` with OctoMap's ray casting instead of the footprint test: every voxel a pixel's
        ray passes more than a voxel before its measured surface is free (rays of every k-th pixel,
        k = ceil(W / max_width)). Thin rims seen edge-on can be carved, so a map for planning keeps
        `integrate`; near surfaces seen at a grazing angle, where every footprint also holds nearer
        pixels, this carves what the rays saw, which a map that estimates the unseen needs."""
        depth = _checked_frame(depth, K, T_wc)
        hit, evidence = self._hits(depth, K, T_wc, no_return)
        k = max(1, -(-depth.shape[1] // max_width))
        rays = pixel_rays(depth.shape[1], depth.shape[0], np.asarray(K, float))[k // 2::k, k // 2::k].reshape(-1, 3)
        reach = evidence[k // 2::k, k // 2::k].reshape(-1).astype(float)
        keep = reach > 0
        norms = np.linalg.norm(rays[keep], axis=1)
        reach = np.minimum(reach[keep], self.free_range) * norms - self.voxel_size
        dirs = rays[keep] / norms[:, None] @ np.asarray(T_wc, float)[:3, :3].T
        step = 0.5 * self.voxel_size
        free = np.zeros(self.shape, bool)
        for s in range(0, len(dirs), RAYS_PER_BLOCK):
            d, r = dirs[s:s + RAYS_PER_BLOCK], reach[s:s + RAYS_PER_BLOCK]
            t = step * (np.arange(max(0, int(np.ceil(r.max(initial=0.0) / step)))) + 0.5)
            along = t[None, :] < r[:, None]
            pts = T_wc[:3, 3] + d[:, None, :] * t[None, :, None]
            idx = self._index(pts[along])
            idx = idx[self._inside(idx)]
            free[idx[:, 0], idx[:, 1], idx[:, 2]] = True
        self._apply(hit, free)

    def _hits(self, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, no_return: float) -> tuple[np.ndarray,
                                                                                                np.ndarray]:
        """The voxels holding a measured point, and each pixel's evidence: its depth, `no_return` for a
        pixel without a return, 0 for no evidence."""
        pts, valid = backproject_depth(depth, K, T_wc)
        hit = np.zeros(self.shape, bool)
        if len(pts):
            idx = self._index(pts)
            ok = self._inside(idx)
            hit[idx[ok, 0], idx[ok, 1], idx[ok, 2]] = True
        evidence = np.where(valid, depth, np.where(depth == 0, np.float32(no_return), 0.0)).astype(np.float32)
        return hit, evidence

    def mark_free_sphere(self, center: np.ndarray, radius: float) -> None:
        """Declare the unknown voxels within `radius` of `center` free (the volume the drone occupies:
        its own body proves it empty). Voxels with evidence keep it."""
        near = self._around(center, radius)
        if near is not None:
            box, dx, dy, dz = near
            self.observed[box] |= dx**2 + dy**2 + dz**2 <= radius**2

    def mark_blind_free(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int, radius: float,
                        z_range: tuple[float, float]) -> None:
        """Declare free the unknown voxels within `radius` of the camera that lie above or below its
        vertical field of view, or reach past it, at any heading (the blind cones overhead and
        underfoot that no turn in place can look into), and between the heights `z_range`. Voxels
        with evidence keep it."""
        h = self.voxel_size
        c = np.asarray(T_wc, float)[:3, 3]
        near = self._around(c, radius)
        if near is None:
            return
        box, dx, dy, dz = near
        dist = np.sqrt(dx**2 + dy**2 + dz**2)
        axis = float(np.arcsin(np.clip(T_wc[2, 2], -1.0, 1.0)))  # the optical axis's elevation
        # Blind: a turn in place does not reliably carve it. Seen at the image's side edge (where a
        # turn's views meet, and the vertical view is narrowest), its footprint (`integrate`) reaches
        # past the image's top or bottom edge.
        side = math.cos(math.atan2(0.5 * width, K[0, 0]))
        z_c = np.maximum(np.hypot(dx, dy) * side, h)
        rows = K[1, 1] * np.abs(np.tan(np.arctan2(dz, z_c / side) - axis)) / side + footprint_px(h, K[1, 1], z_c)
        gz = c[2] + dz
        self.observed[box] |= (dist <= radius) & (rows > 0.5 * height) & (gz >= z_range[0]) & (gz <= z_range[1])

    def _around(self, center: np.ndarray, radius: float) -> tuple[tuple[slice, ...], np.ndarray, np.ndarray,
                                                                   np.ndarray] | None:
        """The grid's box of voxels within `radius` of `center` along each axis, and their centers'
        offsets from it (dx, dy, dz over the box); None when the box misses the grid."""
        h = self.voxel_size
        c = np.asarray(center, float)
        lo = np.maximum(np.floor((c - radius - self.origin) / h).astype(int), 0)
        hi = np.minimum(np.ceil((c + radius - self.origin) / h).astype(int) + 1, self.shape)
        if np.any(hi <= lo):
            return None
        axes = [self.origin[a] + (np.arange(lo[a], hi[a]) + 0.5) * h - c[a] for a in range(3)]
        return (tuple(slice(a, b) for a, b in zip(lo, hi)), *np.meshgrid(*axes, indexing="ij"))

    def state(self, points: np.ndarray) -> np.ndarray:
        """UNKNOWN / FREE / OCCUPIED of the voxel holding each point (N, 3); outside the grid: UNKNOWN."""
        idx = self._index(np.asarray(points, float).reshape(-1, 3))
        ok = self._inside(idx)
        out = np.full(len(idx), UNKNOWN, np.int8)
        i, j, k = idx[ok].T
        out[ok] = np.where(self.surface[i, j, k], OCCUPIED, np.where(self.observed[i, j, k], FREE, UNKNOWN))
        return out

    def unknown_ends(self, origins: np.ndarray, directions: np.ndarray, t_min: float,
                     t_max: float) -> tuple[np.ndarray, np.ndarray]:
        """The unknown space each ray ends in: per ray (origins and unit directions (R, 3)), the length
        (m) of the unbroken run of unknown samples (every half voxel between t_min and t_max) just
        before its first occupied voxel, or before t_max when it meets none, and the distance where
        that run begins (nan when there is none). Unknown space a ray leaves again for known free
        space (the unseen strip beside a camera) ends nothing. Outside the grid counts as unknown,
        as in `state`."""
        o = np.asarray(origins, float).reshape(-1, 3)
        d = np.asarray(directions, float).reshape(-1, 3)
        step = 0.5 * self.voxel_size
        t = t_min + step * (np.arange(max(0, int(np.ceil((t_max - t_min) / step)))) + 0.5)
        if len(t) == 0 or len(o) == 0:
            return np.zeros(len(o)), np.full(len(o), np.nan)
        states = self.state(o[:, None, :] + d[:, None, :] * t[None, :, None]).reshape(len(o), len(t))
        before = np.cumsum(states == OCCUPIED, axis=1) == 0
        last_known = np.where(before & (states != UNKNOWN), np.arange(len(t)), -1).max(axis=1)
        run = before.sum(axis=1) - 1 - last_known
        entry = np.where(run > 0, t[np.minimum(last_known + 1, len(t) - 1)], np.nan)
        return run * step, entry

    def occupied(self) -> np.ndarray:
        return self.surface.copy()

    def free(self) -> np.ndarray:
        return self.observed & ~self.surface

    def blocked(self) -> np.ndarray:
        """Not flyable: occupied or unknown."""
        return ~self.free()

    def distance_field(self, unknown_offset: float = 0.0) -> DistanceField:
        """Clearance to everything not known free (unknown counts as an obstacle).

        With `unknown_offset` > 0 the reading near unknown space is raised by it: a planner that
        requires body radius + safety margin then keeps the margin from what it saw occupied but
        only the body from what it has not seen (min(d_occupied, d_unknown + offset))."""
        if unknown_offset <= 0:
            return DistanceField.from_blocked(self.blocked(), self.origin, self.voxel_size, signed=False)
        occupied = DistanceField.from_blocked(self.occupied(), self.origin, self.voxel_size, signed=False)
        unknown = DistanceField.from_blocked(~self.observed, self.origin, self.voxel_size, signed=False)
        values = np.minimum(occupied.values, unknown.values + np.float32(unknown_offset))
        return DistanceField(values, self.origin, self.voxel_size)

    def _index(self, pts: np.ndarray) -> np.ndarray:
        return np.floor((pts - self.origin) / self.voxel_size).astype(np.int64)

    def _inside(self, idx: np.ndarray) -> np.ndarray:
        return np.all((idx >= 0) & (idx < np.array(self.shape)), axis=1)

    def _apply(self, hit: np.ndarray, passed: np.ndarray | None) -> None:
        self.surface |= hit
        self.observed |= hit
        if passed is not None:
            self.observed |= passed


def _checked_frame(depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> np.ndarray:
    """The depth as float32; a frame of the wrong shape or a non-finite pose is a DataError."""
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 2 or np.asarray(K).shape != (3, 3) or np.asarray(T_wc).shape != (4, 4):
        raise DataError(f"occupancy update needs an HxW depth, a 3x3 K and a 4x4 pose; got shapes "
                        f"{depth.shape}, {np.asarray(K).shape}, {np.asarray(T_wc).shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(T_wc))):
        raise DataError("occupancy update: the camera pose or intrinsics hold NaN or infinity")
    return depth


def footprint_px(voxel: float, focal: float, depth: np.ndarray) -> np.ndarray:
    """Half-width (px) of the square of pixels that must all pass a voxel at z-depth `depth` for
    it to be carved: its projected half-diagonal, rounded up to FOOTPRINT_PX."""
    need = np.float32(0.5 * np.sqrt(3) * voxel * focal) / np.asarray(depth, np.float32)
    return FOOTPRINT_PX[np.minimum(np.searchsorted(FOOTPRINT_PX, need), len(FOOTPRINT_PX) - 1)]


def _footprint_min_depth(depth: np.ndarray, u: np.ndarray, v: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Smallest depth in the square of half-width `radius` px around each pixel (u, v); 0 (invalid)
    wins, and pixels beyond the image border count as 0: a footprint touching a pixel without depth,
    or reaching past the image, carves nothing."""
    out = np.empty(len(u), np.float32)
    for r in np.unique(radius):
        m = radius == r
        lowest = ndimage.minimum_filter(depth, size=2 * int(r) + 1, mode="constant", cval=0.0)
        out[m] = lowest[v[m], u[m]]
    return out
