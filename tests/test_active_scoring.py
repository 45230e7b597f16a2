"""Reliability update and 2D GauSS-MI against brute-force per-pixel evaluation on tiny scenes.

The brute force gets T^[i,j] for every splat and pixel by rendering one-hot features (channel i of
the image is splat i's blending weight), then applies Eq. 14 and Eq. 22 as written, with loops.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch

from flightrecon.active import gaussmi2d, reliability
from flightrecon.active.reliability import ReliabilityConfig
from flightrecon.geometry import camera_pose, intrinsics, pixel_rays
from flightrecon.render import render, render_view_with_sums
from splat_scenes import wall

CFG = ReliabilityConfig()
W, H = 24, 18
BACKENDS = ["reference", "cpu"]


def _weights(s, T_wc, K, backend) -> torch.Tensor:
    """T^[i,j] as an [N,H,W] tensor via one-hot features."""
    N = s["means"].shape[0]
    out = render(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], torch.eye(N),
                 torch.linalg.inv(T_wc)[None], K[None], W, H, outputs=("features",), backend=backend)
    return out.features[0].permute(2, 0, 1)


def _cam(pos, yaw):
    return torch.tensor(camera_pose(np.array(pos, float), yaw), dtype=torch.float32)


K = torch.tensor(intrinsics(W, H, 90.0), dtype=torch.float32)


@pytest.mark.parametrize("backend", BACKENDS)
def test_pixel_sums_equal_brute_force(backend):
    s = wall()
    T = _cam([0.0, 0.1, 1.2], 0.0)
    v = torch.rand(H, W, generator=torch.Generator().manual_seed(0))
    view = render_view_with_sums(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], s["colors"],
                                 torch.linalg.inv(T), K, W, H, backend=backend)
    sums = view.splat_sums(v)
    Tij = _weights(s, T, K, backend)
    brute = torch.tensor([sum(float(v[j, k] * Tij[i, j, k]) for j in range(H) for k in range(W))
                          for i in range(Tij.shape[0])])
    assert (brute > 0).all()
    torch.testing.assert_close(sums, brute, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_pixel_sums_of_values_computed_from_the_render_itself(backend):
    """A loss image made from the render carries the render's graph; its pixel sums must still be
    sum_p v(p) w_i(p), not the product rule's extra sum_p F(p) dv/df_i (the GauSS-MI port's bug: half
    of the splats took negative evidence from a map that fit its frames)."""
    s = wall()
    s["colors"] = torch.linspace(0.2, 0.8, 27).reshape(9, 3)
    T = _cam([0.0, 0.1, 1.2], 0.0)
    view = render_view_with_sums(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], s["colors"],
                                 torch.linalg.inv(T), K, W, H, backend=backend)
    observed = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1))
    loss = (view.output.features[0] - observed).abs().mean(-1)
    assert loss.requires_grad  # the trap: v depends on the features through the render
    v = -torch.log((1.7 * loss).clamp_min(1e-4))
    Tij = _weights(s, T, K, backend)
    brute = (Tij.double() * v.detach().double()[None]).sum(dim=(1, 2))
    torch.testing.assert_close(view.splat_sums(v).double(), brute, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_update_sides_and_gating(backend):
    s = wall()
    N = s["means"].shape[0]
    rel0 = torch.zeros(N, 2)
    rgb = torch.full((H, W, 3), 0.5)

    def update(T):
        depth = torch.zeros(H, W, 1)  # no valid depth: the color term alone decides L
        view = render_view_with_sums(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], s["colors"],
                                     torch.linalg.inv(T), K, W, H, backend=backend)
        return reliability.update_from_frame(view, s, rel0, rgb, depth, T, K, CFG, ssim_weight=0.0)[0]

    front = update(_cam([0.0, 0.0, 1.2], 0.0))  # head-on, rendered color equals observed where opaque
    assert (front[:, 0] > 0).any() and (front[:, 1] == 0).all()
    behind = update(_cam([4.0, 0.0, 1.2], math.pi))  # same wall seen from +x: back side
    assert (behind[:, 1] > 0).any() and (behind[:, 0] == 0).all()
    edge_on = update(_cam([2.0, -3.0, 1.2], math.pi / 2))  # camera in the wall's plane
    torch.testing.assert_close(edge_on, rel0)
    away = update(_cam([0.0, 0.0, 1.2], math.pi))  # looking away: out of view
    torch.testing.assert_close(away, rel0)


def test_update_formula_matches_eq14_by_hand():
    s = wall(1)  # one splat at (2, -0.3, 0.9)
    T = _cam([0.0, -0.3, 0.9], 0.0)
    v = torch.rand(H, W, generator=torch.Generator().manual_seed(1))
    Tij = _weights(s, T, K, "reference")
    w = reliability.observation_weights(s["means"], reliability.splat_normals(s["quats"]), T[None, :3, 3])[0]
    sums = (Tij * v).sum(dim=(1, 2))
    new = reliability.reliability_update(torch.zeros(1, 2), w, sums, CFG)
    assert float(w[0]) == pytest.approx(1.0, abs=1e-5)
    assert float(new[0, 0]) == pytest.approx(min(CFG.lambda_T * float(w[0]) * float(sums[0]), 10.0), rel=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_mi_equals_brute_force_eq22(backend):
    s = wall()
    N = s["means"].shape[0]
    rel = torch.linspace(-3.0, 4.0, 2 * N).reshape(N, 2)
    poses = torch.stack([_cam([0.0, 0.0, 1.2], 0.0), _cam([0.3, -0.4, 1.0], 0.3), _cam([4.0, 0.2, 1.2], math.pi)])
    mi = gaussmi2d.score_candidates(s, rel, poses, K, W, H, w_min=CFG.w_min, near=0.05, far=10.0, backend=backend)
    normals = reliability.splat_normals(s["quats"])
    for c in range(len(poses)):
        Tij = _weights(s, poses[c], K, backend)
        w = reliability.observation_weights(s["means"], normals, poses[c][None, :3, 3])[0]
        total = 0.0
        for i in range(N):
            if abs(float(w[i])) <= CFG.w_min:
                continue
            side = 0 if w[i] > 0 else 1
            p = 1.0 / (1.0 + math.exp(-float(rel[i, side])))
            total += -abs(float(w[i])) * math.log(p) * float(Tij[i].sum())
        assert float(mi[c]) == pytest.approx(total, rel=1e-4)
    assert float(mi[2]) > 0  # the back side is scored from behind


@pytest.mark.parametrize("backend", BACKENDS)
def test_unreliable_surface_scores_higher(backend):
    left, right = wall(x=2.0), wall(x=2.0)
    right["means"] = right["means"] + torch.tensor([0.0, 3.0, 0.0])  # a second wall to the +y side
    s = {k: torch.cat([left[k], right[k]]) for k in left}
    n = left["means"].shape[0]
    rel = torch.zeros(2 * n, 2)
    rel[:n, 0] = 8.0  # the left wall is well reconstructed
    poses = torch.stack([_cam([0.0, 0.0, 1.2], 0.0), _cam([0.0, 3.0, 1.2], 0.0)])
    mi = gaussmi2d.score_candidates(s, rel, poses, K, W, H, w_min=0.1, near=0.05, far=10.0, backend=backend)
    assert float(mi[1]) > 10 * float(mi[0]) > 0


def test_depth_noise_prior_is_one_at_best_range_and_decreasing():
    d = torch.tensor([0.0, 0.3, 0.4, 1.0, 3.0])
    p = gaussmi2d.depth_noise_prior(d)
    assert p[0] == 0 and p[1] == 1 and p[2] == 1 and 1 > p[3] > p[4] > 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_shared_render_gives_the_sums_of_a_unit_feature_render(backend):
    """The loop's one render at the capture pose (colors, depth, normal) gives the same per-splat sums
    as a render of a unit feature of its own (the reliability update's render before it was shared)."""
    s = wall(4)
    T = _cam([0.1, 0.05, 1.1], 0.1)
    v = torch.rand(H, W, generator=torch.Generator().manual_seed(2)) * 9.0
    view = render_view_with_sums(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], s["colors"],
                                 torch.linalg.inv(T), K, W, H, backend=backend)
    ones = torch.ones(len(s["means"]), 1, requires_grad=True)
    out = render(s["means"], s["quats"], s["log_scales"], s["opacity_logits"], ones, torch.linalg.inv(T)[None],
                 K[None], W, H, outputs=("features",), backend=backend)
    (unit,) = torch.autograd.grad((out.features[0, ..., 0] * v).sum(), ones)
    assert torch.equal(view.splat_sums(v), unit[:, 0])
    assert torch.equal(view.splat_sums(2 * v), 2 * unit[:, 0])  # the graph serves a second question


def test_edge_mask_drops_depth_and_normal_terms_only_at_observed_occlusion_edges():
    """A step in the observed depth (a box in front of a wall): with edge_mask the loss image loses
    its depth and normal terms on the pixels next to the step and nowhere else."""
    H, W = 24, 32
    K = intrinsics(W, H, 90.0)
    rays = torch.as_tensor(pixel_rays(W, H, K), dtype=torch.float32)
    depth_obs = torch.full((H, W, 1), 3.0)
    depth_obs[8:16, 10:20] = 1.5
    depth_obs[0, 0] = 0.0  # a hole: its neighbours border invalid depth
    depth = depth_obs + 0.2  # the map renders everything 20 cm too far
    color = torch.full((H, W, 3), 0.5)
    normal = torch.zeros(H, W, 3)
    normal[..., 2] = -1.0
    cfg = ReliabilityConfig()
    plain = reliability.loss_image(color, depth, normal, color, depth_obs, rays, cfg, ssim_weight=0.0)
    masked = reliability.loss_image(color, depth, normal, color, depth_obs, rays,
                                    dataclasses.replace(cfg, edge_mask=True), ssim_weight=0.0)
    edge = reliability.depth_edges(depth_obs[..., 0])
    assert bool(edge[7, 12]) and bool(edge[8, 12]) and bool(edge[0, 1]) and not bool(edge[4, 4])
    torch.testing.assert_close(masked[~edge], plain[~edge], rtol=0, atol=0)
    assert torch.all(masked[edge] == 0.0)  # color identical: nothing left at the edges
    assert torch.all(plain[edge & (depth_obs[..., 0] > 0)] > 0)
