"""New splats from one RGB-D frame (the paper's Section III-B, 2DGS-SLAM's recipe).

Centers are back-projected valid depth pixels (a random, seeded share of them); the normal comes from
the cross product of the depth image's central differences, oriented toward the camera; color is
the pixel's; both scales are the RMS distance to the 3 nearest new centers (clamped); opacity is
`init_opacity`. Pixels with invalid depth (0, NaN, out of range) seed nothing; pixels at occlusion
edges and on thin structures seed splats with one-sided normals (see `depth_normals`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from flightrecon.geometry import pixel_rays

# A neighbour whose depth differs by more than this share is across an occlusion edge.
_MAX_REL_DEPTH_JUMP = 0.05
# Largest second difference of inverse depth, relative to it, still taken as one smooth surface.
_MAX_REL_BEND = 0.01


def valid_depth_mask(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """Finite depth strictly inside (near, far]; everything else is a sensor dropout."""
    d = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > near) & (d <= far)


def depth_normals(depth: np.ndarray, K: np.ndarray, valid: np.ndarray,
                  edges: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit normals (H, W, 3) facing the camera, and the mask where they are defined.

    The normal is the cross product of the central differences along x and y. Inside one smooth
    surface that is all; with `edges`, pixels next to an occlusion edge use the one-sided difference
    toward the neighbour on their own surface, and an axis with no such neighbour (a structure one or
    two pixels wide, like a lamp pole) leaves the normal the most camera-facing direction across the
    other axis' tangent (or the reversed ray with neither). Without these, thin structures and object
    outlines never seed a splat and cannot be reconstructed at all. Creases (both neighbours on the
    surface but bent) and the image border stay undefined.
    """
    d = np.where(valid, depth, 0.0).astype(np.float64)
    P = pixel_rays(d.shape[1], d.shape[0], K) * d[..., None]
    H, W = d.shape
    n = np.zeros((H, W, 3))
    ok = np.zeros((H, W), bool)
    Pc = P[1:-1, 1:-1]
    center = d[1:-1, 1:-1]
    nb = np.stack([d[1:-1, 2:], d[1:-1, :-2], d[2:, 1:-1], d[:-2, 1:-1]])  # right, left, down, up
    Pnb = np.stack([P[1:-1, 2:], P[1:-1, :-2], P[2:, 1:-1], P[:-2, 1:-1]])
    same = (nb > 0) & (np.abs(nb - center) <= _MAX_REL_DEPTH_JUMP * center)
    # Inverse depth is affine in pixel coordinates on a plane: a second difference far from zero
    # means a crease or an occlusion edge inside the stencil, where the cross product mixes surfaces.
    with np.errstate(divide="ignore"):
        inv = np.where(nb > 0, 1.0 / np.where(nb > 0, nb, 1.0), 0.0)
        inv_c = 1.0 / np.where(center > 0, center, 1.0)
    tangents, defined = [], []
    crease = np.zeros(center.shape, bool)
    for a in (0, 2):  # x (right, left), y (down, up)
        both = same[a] & same[a + 1]
        smooth = np.abs(inv[a] + inv[a + 1] - 2 * inv_c) <= _MAX_REL_BEND * inv_c
        crease |= both & ~smooth
        t = Pnb[a] - Pnb[a + 1]
        if edges:
            t = np.where((~both & same[a])[..., None], Pnb[a] - Pc, t)
            t = np.where((~both & ~same[a] & same[a + 1])[..., None], Pc - Pnb[a + 1], t)
            defined.append(same[a] | same[a + 1])
        else:
            defined.append(both)
        tangents.append(t)
    dx, dy = tangents
    c = np.cross(dy, dx)  # faces the camera for a frontal plane: (0,1,0) x (1,0,0) = (0,0,-1)
    good = valid[1:-1, 1:-1] & defined[0] & defined[1] & ~crease
    if edges:
        one = valid[1:-1, 1:-1] & (defined[0] ^ defined[1]) & ~crease
        t = np.where(defined[0][..., None], dx, dy)
        t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-30)
        facing = -Pc - np.einsum("hwc,hwc->hw", -Pc, t)[..., None] * t
        c = np.where(one[..., None], facing, c)
        none = valid[1:-1, 1:-1] & ~defined[0] & ~defined[1]
        c = np.where(none[..., None], -Pc, c)
        good |= one | none
    norm = np.linalg.norm(c, axis=-1)
    good &= norm > 1e-12 * np.maximum(center, 1e-30) ** 2
    c = c / np.maximum(norm, 1e-30)[..., None]
    flip = np.einsum("hwc,hwc->hw", c, Pc) > 0  # must point back toward the camera
    c[flip] *= -1.0
    n[1:-1, 1:-1] = c
    ok[1:-1, 1:-1] = good
    return n, ok


def frame_candidates(rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_wc: np.ndarray, *, near: float,
                     far: float, subsample: float, rng: np.random.Generator,
                     edges: bool = True, eligible: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """World points, normals and colors of a random `subsample` share of the usable pixels (of those
    in the `eligible` mask [H, W], when given)."""
    valid = valid_depth_mask(depth, near, far)
    normals_c, ok = depth_normals(depth, K, valid, edges)
    if eligible is not None:
        ok &= eligible
    vs, us = np.nonzero(ok)
    count = int(round(subsample * vs.size))
    pick = np.sort(rng.choice(vs.size, size=count, replace=False)) if count < vs.size else np.arange(vs.size)
    vs, us = vs[pick], us[pick]
    d = depth[vs, us].astype(np.float64)
    rays = np.stack([(us + 0.5 - K[0, 2]) / K[0, 0], (vs + 0.5 - K[1, 2]) / K[1, 1], np.ones_like(d)], axis=1)
    R, t = T_wc[:3, :3], T_wc[:3, 3]
    return {
        "points": (rays * d[:, None]) @ R.T + t,
        "normals": normals_c[vs, us] @ R.T,
        "colors": np.asarray(rgb, np.float64)[vs, us, :3],
    }


def quats_from_normals(normals: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of the smallest rotation taking +z to each unit normal (the splat's tangent frame)."""
    n = np.asarray(normals, np.float64)
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], axis=1)
    antipodal = q[:, 0] < 1e-6
    q[antipodal] = (0.0, 1.0, 0.0, 0.0)  # half-turn about x takes +z to -z
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def splat_params(points: np.ndarray, normals: np.ndarray, colors: np.ndarray, *, opacity: float,
                 min_scale: float, max_scale: float) -> dict[str, np.ndarray]:
    """Splat parameters (float32 arrays) for the given centers; scales from 3-NN spacing."""
    m = len(points)
    if m >= 2:
        k = min(3, m - 1)
        dist, _ = cKDTree(points).query(points, k=k + 1)
        scale = np.sqrt(np.mean(np.square(dist[:, 1:]), axis=1))
    else:
        scale = np.full(m, max_scale)
    scale = np.clip(scale, min_scale, max_scale)
    logit = np.log(opacity / (1.0 - opacity))
    return {
        "means": points.astype(np.float32),
        "quats": quats_from_normals(normals).astype(np.float32),
        "log_scales": np.repeat(np.log(scale)[:, None], 2, axis=1).astype(np.float32),
        "opacity_logits": np.full(m, logit, np.float32),
        "colors": np.clip(colors, 0.0, 1.0).astype(np.float32),
    }
