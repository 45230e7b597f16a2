"""Color fidelity of the MuJoCo render against an independent reference projection of the mesh.

The reference is a numpy z-buffer rasterizer written here from first principles: per pixel center,
the nearest triangle containing it, perspective-correct barycentric coordinates, the interpolated
vertex color (unlit) and the z-depth. It shares no code with the world or the bake; only
`geometry` for the pose and the pixel-center convention.
"""

from __future__ import annotations

import flightrecon  # noqa: F401  (selects EGL before mujoco loads)

import numpy as np
import pytest

from flightrecon.geometry import camera_pose, invert_pose
from flightrecon.scenario import load_config
from flightrecon.scene.procedural import make_scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world


def rasterize(vertices, faces, colors, T_wc, K, width, height, near=0.05):
    """(rgb float (H,W,3) in [0,1], depth (H,W), hit mask (H,W))."""
    T_cw = invert_pose(np.asarray(T_wc, float))
    pc = np.asarray(vertices, float) @ T_cw[:3, :3].T + T_cw[:3, 3]
    faces = np.asarray(faces)
    tri = pc[faces]  # (F, 3, 3)
    keep = np.all(tri[:, :, 2] > near, axis=1)
    faces, tri = faces[keep], tri[keep]
    z = tri[:, :, 2]
    u = K[0, 0] * tri[:, :, 0] / z + K[0, 2]
    v = K[1, 1] * tri[:, :, 1] / z + K[1, 2]
    i0 = np.clip(np.ceil(u.min(1) - 0.5), 0, width).astype(int)
    i1 = np.clip(np.floor(u.max(1) - 0.5), -1, width - 1).astype(int)
    j0 = np.clip(np.ceil(v.min(1) - 0.5), 0, height).astype(int)
    j1 = np.clip(np.floor(v.max(1) - 0.5), -1, height - 1).astype(int)
    bw, bh = i1 - i0 + 1, j1 - j0 + 1
    ok = (bw > 0) & (bh > 0)
    cols = np.asarray(colors, float)[faces] / 255.0  # (F, 3, 3)
    pix_all, z_all, c_all = [], [], []
    size = np.maximum(bw, bh)
    for lo, hi in ((0, 4), (4, 16), (16, 64), (64, 1 << 30)):
        sel = np.nonzero(ok & (size > lo) & (size <= hi))[0]
        step = max(1, 4_000_000 // max(1, min(hi, max(width, height)) ** 2))
        for s in range(0, len(sel), step):
            idx = sel[s:s + step]
            n = int(min(hi, size[idx].max()))
            oy, ox = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
            px = i0[idx, None, None] + ox[None]
            py = j0[idx, None, None] + oy[None]
            valid = (px <= i1[idx, None, None]) & (py <= j1[idx, None, None])
            cx, cy = px + 0.5, py + 0.5
            ua, va = u[idx, 0, None, None], v[idx, 0, None, None]
            ub, vb = u[idx, 1, None, None], v[idx, 1, None, None]
            uc, vc = u[idx, 2, None, None], v[idx, 2, None, None]
            area = (ub - ua) * (vc - va) - (uc - ua) * (vb - va)
            with np.errstate(divide="ignore", invalid="ignore"):
                l1 = ((cx - ua) * (vc - va) - (uc - ua) * (cy - va)) / area
                l2 = ((ub - ua) * (cy - va) - (cx - ua) * (vb - va)) / area
            l0 = 1 - l1 - l2
            eps = -1e-9
            inside = valid & (l0 >= eps) & (l1 >= eps) & (l2 >= eps) & (np.abs(area) > 1e-12)
            w = np.stack([l0 / z[idx, 0, None, None], l1 / z[idx, 1, None, None], l2 / z[idx, 2, None, None]], -1)
            wsum = w.sum(-1)
            f, a, b = np.nonzero(inside)
            wp = w[f, a, b] / wsum[f, a, b, None]
            pix_all.append(py[f, a, b] * width + px[f, a, b])
            z_all.append(1.0 / wsum[f, a, b])
            c_all.append(np.einsum("nk,nkc->nc", wp, cols[idx[f]]))
    pix = np.concatenate(pix_all)
    zz = np.concatenate(z_all)
    cc = np.concatenate(c_all)
    order = np.lexsort((zz, pix))
    pix, zz, cc = pix[order], zz[order], cc[order]
    first = np.ones(len(pix), bool)
    first[1:] = pix[1:] != pix[:-1]
    rgb = np.zeros((height * width, 3))
    depth = np.zeros(height * width)
    rgb[pix[first]] = cc[first]
    depth[pix[first]] = zz[first]
    hit = np.zeros(height * width, bool)
    hit[pix[first]] = True
    return rgb.reshape(height, width, 3), depth.reshape(height, width), hit.reshape(height, width)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2)))


@pytest.mark.slow
@pytest.mark.parametrize("name, position, yaw, pitch", [
    ("room0", [0.2, 0.1, 1.2], 3.5, 20.0),
    ("office0", [0.3, -0.4, 1.4], 1.0, 15.0),
])
def test_render_matches_reference_projection(tmp_path, name, position, yaw, pitch):
    scene = make_scene(name)
    world = build_world(scene, load_config(None, [f'scene.cache_dir="{tmp_path}"']), with_drone=False)
    W, H = 320, 240
    cam = RGBDCamera(world, W, H, 90.0, 0.05, 10.0)
    T = camera_pose(position, yaw, pitch)
    rgb, depth = cam.render(T)
    ref, ref_depth, hit = rasterize(scene.vertices, scene.faces, scene.vertex_colors, T, cam.K, W, H)
    assert hit.all() and (depth > 0).all()
    assert psnr(rgb, ref) >= 30.0
    assert np.median(np.abs(depth - ref_depth)) < 1e-4
    assert np.mean(np.abs(depth - ref_depth) > 0.01) < 0.01  # only silhouette pixels may differ
