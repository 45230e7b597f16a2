"""`activegs_native`: ActiveGS choosing among its own candidates, as its public code generates them
(planning/plan_base.py, planning/utils.py, mapping/voxel_map.py), instead of our shared library.
Our planner still decides which of them a quadrotor can reach.

Per step it proposes up to 100 views: first views at regions of interest, taken nearest first, up
to 5 each until at least 30; then random views at free voxel centers within 0.5 m of the drone.
A region of interest is a free voxel next to unexplored space (a frontier) or a voxel holding more
than 5 high-opacity (> 0.7), low-confidence (< 0.3) splats, kept when it borders free space. Its
views stand at free voxel centers (0.3 m clear of occupied voxels) 0.3-2.0 m from it, within 60
degrees of the direction it faces (the splats' mean normal, or for a frontier the mean direction to
its free neighbours), looking at it. A quadrotor's camera cannot pitch: each view keeps the heading
of its direction (ActiveGS's own runs allow pitch), and a random view takes a random heading.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.ndimage import binary_dilation, generate_binary_structure

from flightrecon.active.baselines import ActiveGSSelector, VoxelMap
from flightrecon.active.protocol import MapView
from flightrecon.active.reliability import splat_normals

ALL_VIEWS, ROI_VIEWS, VIEWS_PER_ROI = 100, 30, 5  # its sample_num, max_roi_sample_num, sample_per_roi
ROI_NEAR, ROI_FAR, ROI_COSINE = 0.3, 2.0, 0.5  # m, m, cosine to the region's facing direction
RANDOM_RADIUS = 0.5  # m, its planner `radius`
SAFETY_MARGIN = 0.3  # m, free voxels this far from occupied ones are candidate positions
LOW_CONFIDENCE, HIGH_OPACITY, MIN_SPLATS = 0.3, 0.7, 5


def _grid(vm: VoxelMap, flat: torch.Tensor) -> np.ndarray:
    return flat.numpy().reshape(*vm.dims)


def free_with_margin(vm: VoxelMap, margin: float = SAFETY_MARGIN) -> np.ndarray:
    """[M] free voxels farther than `margin` (a sphere in voxel offsets) from any occupied one."""
    r = margin / float(vm.size.min())
    n = int(math.floor(r))
    L = np.arange(-n, n + 1)
    X, Y, Z = np.meshgrid(L, L, L, indexing="ij")
    near_occupied = binary_dilation(_grid(vm, vm.occupied), structure=(X ** 2 + Y ** 2 + Z ** 2) <= r * r)
    return vm.free.numpy() & ~near_occupied.reshape(-1)


def regions_of_interest(vm: VoxelMap, means: torch.Tensor, normals: torch.Tensor, confidence: torch.Tensor,
                        opacity: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(flat indices [R] of the regions of interest, their facing normals [R,3]; zero for a frontier
    voxel without low-confidence splats)."""
    six = generate_binary_structure(3, 1)
    free = vm.free.numpy()
    frontier = binary_dilation(_grid(vm, vm.unexplored), structure=six).reshape(-1) & free
    idx = vm.index(means)
    weak = (idx >= 0) & (confidence < LOW_CONFIDENCE) & (opacity > HIGH_OPACITY)
    count = np.bincount(idx[weak].numpy(), minlength=vm.size_total)
    normal_sum = np.zeros((vm.size_total, 3))
    np.add.at(normal_sum, idx[weak].numpy(), normals[weak].double().numpy())
    low_conf = count > MIN_SPLATS
    normal = np.zeros((vm.size_total, 3))
    normal[low_conf] = normal_sum[low_conf] / np.linalg.norm(normal_sum[low_conf], axis=1, keepdims=True).clip(1e-12)
    roi = (frontier | low_conf) & binary_dilation(free.reshape(*vm.dims), structure=six).reshape(-1)
    keep = np.flatnonzero(roi)
    return keep, normal[keep]


def free_direction(vm: VoxelMap, free: np.ndarray, flat: int) -> np.ndarray | None:
    """Mean unit direction from voxel `flat` to its free (`free` [M]) 26-neighbours, or None without one."""
    ijk = np.array(np.unravel_index(flat, vm.dims))
    offsets = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)])
    nb = ijk + offsets
    nb = nb[((nb >= 0) & (nb < vm.dims)).all(1)]
    flat_nb = np.ravel_multi_index(nb.T, vm.dims)
    free_nb = flat_nb[free[flat_nb]]
    if len(free_nb) == 0:
        return None
    d = vm.centers[free_nb].numpy() - vm.centers[flat].numpy()
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).mean(0)


def roi_views(vm: VoxelMap, roi: np.ndarray, normals: np.ndarray, free_points: np.ndarray, position: np.ndarray,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Views (positions [V,3], unit view directions [V,3]) at the regions, nearest region first."""
    centers, free = vm.centers.numpy(), vm.free.numpy()
    order = np.argsort(np.linalg.norm(centers[roi] - position, axis=1), kind="stable")
    positions, directions = [], []
    for k in order:
        point, normal = centers[roi[k]], normals[k]
        if not normal.any():
            normal = free_direction(vm, free, roi[k])
        length = np.linalg.norm(normal) if normal is not None else 0.0
        if not length > 1e-9:  # no free neighbour, or free on every side alike: no direction to view it from
            continue
        normal = normal / length
        to_roi = point - free_points
        dist = np.linalg.norm(to_roi, axis=1)
        view = to_roi / dist.clip(1e-12)[:, None]
        ok = np.flatnonzero((dist >= ROI_NEAR) & (dist <= ROI_FAR) & ((view * -normal).sum(1) >= ROI_COSINE))
        if len(ok) > VIEWS_PER_ROI:
            ok = rng.choice(ok, size=VIEWS_PER_ROI, replace=False)
        positions.append(free_points[ok])
        directions.append(view[ok])
        if sum(len(p) for p in positions) >= ROI_VIEWS:
            break
    if not positions:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(positions), np.concatenate(directions)


class ActiveGSNative(ActiveGSSelector):
    """ActiveGS's utility over its own candidates (the module docstring)."""

    name = "activegs_native"

    def propose(self, view: MapView, position: np.ndarray, yaw: float,
                frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Candidate positions [V,3] and headings [V] for this step (none before the first frame)."""
        vm = self.voxels
        if vm is None:
            return np.zeros((0, 3)), np.zeros(0)
        rng = np.random.default_rng([self.cfg.seed, frame, 104723])
        free = free_with_margin(vm)
        free_points = vm.centers.numpy()[free]
        sp = view.splats()
        if len(view):
            roi, normals = regions_of_interest(vm, sp["means"], splat_normals(sp["quats"]), self.confidence(view),
                                               torch.sigmoid(sp["opacity_logits"]))
        else:
            roi, normals = np.zeros(0, int), np.zeros((0, 3))
        pos, dirs = roi_views(vm, roi, normals, free_points, np.asarray(position, float), rng)
        yaws = np.arctan2(dirs[:, 1], dirs[:, 0])
        near = free_points[np.linalg.norm(free_points - position, axis=1) <= RANDOM_RADIUS]
        n_random = ALL_VIEWS - len(pos)
        if n_random > 0 and len(near):
            pos = np.concatenate([pos, near[rng.integers(0, len(near), n_random)]])
            yaws = np.concatenate([yaws, rng.uniform(-math.pi, math.pi, n_random)])
        return pos, yaws
