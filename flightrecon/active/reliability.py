"""Two-sided splat reliability (the paper's Section IV-A, Eqs. 6-15; docs/equations.md).

Each splat keeps two log-odds, front (along its normal, the side first observed, since
initialization orients normals toward the camera) and back. After a frame is mapped, the map is
rendered at the frame's pose and the per-pixel reconstruction loss image

    L = L_C + lambda_rD L_D + lambda_rNr L_Nrend                                         (Eq. 14)

is turned into per-pixel evidence v_j = -log(max(lambda_L L_j, loss_floor)). The per-splat sum
S_i = sum_j v_j T^[i,j] is the gradient of sum_j v_j F_j with respect to the splats' features
(render.rendered_view), so the backward of the loop's one render at the frame's pose gives it for
every splat. The update (Eq. 13) adds lambda_T |w_i| S_i to the side selected by
w_i = n_i . d_i (Eq. 11, 12): front if w_i > w_min, back if w_i < -w_min, no update otherwise.

Bound: L_j -> 0 makes -log(lambda_L L_j) unbounded; L_j is clamped to `loss_floor` (default 1e-4,
GauSS-MI's value), so one pixel adds at most -log(1e-4) = 9.21 nats times lambda_T |w| T. The
log-odds are kept in [-logodds_clamp, logodds_clamp] (default 10, GauSS-MI's), so P stays in
[4.5e-5, 0.99995] and -log P in the MI stays finite.

Loss image details: L_C = (1 - s) |C - C_obs| (mean over RGB) + s (1 - SSIM_j) with the mapper's
D-SSIM weight s and an 11x11 Gaussian SSIM (border pixels, where the window does not fit, use the
L1 term alone); L_D = |D - D_obs| in meters and L_Nrend = 1 - N . N_obs (N_obs from the observed
depth) are added only where the observed depth is valid, and with `edge_mask` not at occlusion edges
of the observed depth (`depth_edges`), where a pixel mixes two surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from flightrecon.config import option
from flightrecon.geometry import pixel_rays
from flightrecon.mapping.image_metrics import ssim_map
from flightrecon.mapping.losses import normals_from_depth
from flightrecon.render import RenderedView
from flightrecon.render.feature_sums import view_cosines
from flightrecon.render.projection import quat_to_rotmat

FRONT, BACK, SKIP = 0, 1, -1
EDGE_JUMP = 0.1  # relative depth step to a 4-neighbour that marks a pixel as an occlusion edge


@dataclass(frozen=True)
class ReliabilityConfig:
    """`[reliability]`: 2D GauSS-MI's settings (the paper's table of parameters), the section of the
    gaussmi2d selectors."""

    w_min: float = option(0.1, 0.0, 1.0)
    lambda_L: float = option(1.0, 1e-6, 1e6)
    lambda_T: float = option(1.2, 0.0, 1e6)
    lambda_rD: float = option(3.0, 0.0, 1e6)
    lambda_rNr: float = option(0.15, 0.0, 1e6)
    loss_floor: float = option(1e-4, 1e-12, 1.0, doc="L_j is clamped to at least this before the log")
    logodds_clamp: float = option(10.0, 0.1, 1e3, doc="log-odds are kept in [-c, c]")
    edge_mask: bool = option(False, doc="leave the depth and normal terms of the loss image out at occlusion edges "
                             "of the observed depth, where a pixel mixes two surfaces and the observed normal is "
                             "undefined (the color term stays); off: the paper's loss image at every pixel")
    measurement_prior: str = option("one", choices=("one", "depth_noise"))
    gain_floor: float = option(0.01, 0.0, 1e6, doc="scoring: a first pass stops a pixel once its transmittance times "
                               "the largest information gain left behind it is below this, bounding each candidate's "
                               "MI from above and below; "
                               "candidates that can still win are scored again exactly, so the chosen view is the "
                               "exact argmax. 0: every candidate exactly")
    moved_from = {"selector.measurement_prior": "measurement_prior", "selector.gain_floor": "gain_floor"}


def splat_normals(quats: torch.Tensor) -> torch.Tensor:
    """World-frame unit normals [N,3] (third column of each splat's rotation)."""
    return quat_to_rotmat(quats)[..., 2]


def observation_weights(means: torch.Tensor, normals: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """w [C,N] = n_i . (c - mu_i) / |c - mu_i| for camera centers [C,3] (Eq. 11)."""
    return view_cosines(means, normals, centers)


def observed_side(w: torch.Tensor, w_min: float) -> torch.Tensor:
    """FRONT (0) where w > w_min, BACK (1) where w < -w_min, SKIP (-1) when nearly edge-on (Eq. 12)."""
    side = torch.full_like(w, SKIP, dtype=torch.long)
    side[w > w_min] = FRONT
    side[w < -w_min] = BACK
    return side


def depth_edges(depth: torch.Tensor) -> torch.Tensor:
    """[H,W] bool: pixels whose depth differs from a 4-neighbour's by more than EDGE_JUMP relative,
    or that border a pixel with no depth (0)."""
    d = depth
    edge = torch.zeros_like(d, dtype=torch.bool)
    for a, b in ((d[1:], d[:-1]), (d[:, 1:], d[:, :-1])):
        jump = (a - b).abs() > EDGE_JUMP * torch.minimum(a, b).clamp_min(1e-6)
        jump |= (a > 0) != (b > 0)
        if a.shape[0] < d.shape[0]:
            edge[1:] |= jump
            edge[:-1] |= jump
        else:
            edge[:, 1:] |= jump
            edge[:, :-1] |= jump
    return edge


def loss_image(color: torch.Tensor, depth: torch.Tensor, normal: torch.Tensor, rgb_obs: torch.Tensor,
               depth_obs: torch.Tensor, rays: torch.Tensor, cfg: ReliabilityConfig,
               ssim_weight: float) -> torch.Tensor:
    """Per-pixel reconstruction loss L [H,W] (Eq. 14) of one rendered view against its observation.

    color [H,W,3], depth [H,W,1], normal [H,W,3] (camera frame), rgb_obs [H,W,3], depth_obs [H,W,1]
    (0 = invalid), rays [H,W,3] pixel directions with z = 1.
    """
    l1 = (color - rgb_obs).abs().mean(-1)
    L = l1.clone()
    r = 5
    H, W = l1.shape
    if ssim_weight > 0 and H > 2 * r and W > 2 * r:
        dssim = 1.0 - ssim_map(color, rgb_obs).mean(-1)
        L[r:-r, r:-r] = (1.0 - ssim_weight) * l1[r:-r, r:-r] + ssim_weight * dssim
    valid = depth_obs[..., 0] > 0
    if cfg.edge_mask:
        valid = valid & ~depth_edges(depth_obs[..., 0])
    n_obs = normals_from_depth(depth_obs, rays)
    has_normal = valid & (n_obs.abs().sum(-1) > 0)
    L_D = (depth - depth_obs).abs()[..., 0]
    L_N = 1.0 - (normal * n_obs).sum(-1)
    L = L + cfg.lambda_rD * torch.where(valid, L_D, 0.0) + cfg.lambda_rNr * torch.where(has_normal, L_N, 0.0)
    return L


def pixel_evidence(L: torch.Tensor, cfg: ReliabilityConfig) -> torch.Tensor:
    """v_j = -log(max(lambda_L L_j, loss_floor)) (the log of Eq. 8's inverse sensing model)."""
    return -torch.log((cfg.lambda_L * L).clamp_min(cfg.loss_floor))


def reliability_update(reliability: torch.Tensor, w: torch.Tensor, sums: torch.Tensor,
                       cfg: ReliabilityConfig, weighted: bool = True) -> torch.Tensor:
    """New log-odds [N,2]: add lambda_T |w| S to the observed side (Eq. 13), clamp, skip edge-on.
    `weighted=False` (an ablation) adds lambda_T S without the |w| factor."""
    side = observed_side(w, cfg.w_min)
    delta = cfg.lambda_T * (w.abs() if weighted else 1.0) * sums
    out = reliability.clone()
    for s in (FRONT, BACK):
        m = side == s
        out[m, s] += delta[m]
    return out.clamp(-cfg.logodds_clamp, cfg.logodds_clamp)


@torch.no_grad()
def update_from_frame(view: RenderedView, splats: dict[str, torch.Tensor], reliability: torch.Tensor,
                      rgb_obs: torch.Tensor, depth_obs: torch.Tensor, T_wc: torch.Tensor, K: torch.Tensor,
                      cfg: ReliabilityConfig, *, ssim_weight: float, weighted: bool = True,
                      one_sided: bool = False) -> tuple[torch.Tensor, dict]:
    """One reliability update after a frame was mapped; returns the new log-odds and diagnostics.

    `view` is the map rendered at the frame's pose after mapping (color, depth, normal; the loop's
    one render of that pose), whose backward gives the per-splat sums; `splats` holds the map's
    current means and quats (for the observation weights).
    Ablations: `weighted=False` drops the |w| factor; `one_sided=True` puts every observation on
    the front log-odds (one reliability per splat, as 3D GauSS-MI without its directions).
    """
    H, W = depth_obs.shape[:2]
    out = view.output
    rays = torch.as_tensor(pixel_rays(W, H, K.cpu().numpy()), dtype=K.dtype, device=K.device)
    L = loss_image(out.features[0], out.depth[0], out.normal[0], rgb_obs, depth_obs, rays, cfg, ssim_weight)
    v = pixel_evidence(L, cfg)
    sums = view.splat_sums(v)
    normals = splat_normals(splats["quats"])
    w = observation_weights(splats["means"], normals, T_wc[None, :3, 3])[0]
    if one_sided:
        w = w.abs()
    new = reliability_update(reliability, w, sums, cfg, weighted)
    touched = (sums != 0) & (w.abs() > cfg.w_min)
    return new, {"loss_mean": float(L.mean()), "updated": int(touched.sum())}
