"""2D GauSS-MI (the paper's Section IV-B, Eqs. 16-22; docs/equations.md): expected mutual information of candidate views.

For candidate n, each splat's information gain is f_n^[i] = -|w_n^[i]| log P(r_obs^[i]) (Eq. 21),
with the side chosen from w_n^[i] = n_i . d_n^[i] exactly as in the reliability update (Eq. 12);
splats seen nearly edge-on from the candidate (|w| <= w_min) carry no gain, as they would get no
update. The MI is I_n = sum_j P(z_j) sum_i f_n^[i] T^[i,j] (Eq. 22): a one-channel image rendered
with per-camera splat features, summed over pixels. With P(z_j) = 1 all candidates of a step go
through one call of the rasterizer's sided feature sums (render.sided_feature_sums: the gain is
formed per visible splat inside it) at the scoring resolution; `information_gain` is its torch
statement.

Measurement prior P(z_j): 1 in simulation (the paper). For real sensors, `depth_noise` uses the
axial noise model of a structured-light RGB-D camera (Nguyen et al. 2012),
sigma(d) = 0.0012 + 0.0019 (d - 0.4)^2 m, and P(z_j) = sigma(d_min) / sigma(d_j) with d_j the
rendered expected depth and d_min = 0.4 m: the relative density of an exact measurement, 1 at the
sensor's best range and falling with distance (0 where nothing is rendered).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from flightrecon.active.candidate_views import render_candidates
from flightrecon.active.reliability import observation_weights, splat_normals
from flightrecon.render import FeatureSums, sided_feature_sums
from flightrecon.render.feature_sums import side_values

_SIGMA_MIN = 0.0012


def depth_noise_prior(depth: torch.Tensor) -> torch.Tensor:
    """P(z_j) from the axial noise model (see module docstring); 0 where depth is 0."""
    sigma = _SIGMA_MIN + 0.0019 * (depth - 0.4).clamp_min(0.0) ** 2
    return torch.where(depth > 0, _SIGMA_MIN / sigma, torch.zeros_like(depth))


def information_gain(reliability: torch.Tensor, w: torch.Tensor, w_min: float,
                     weighted: bool = True) -> torch.Tensor:
    """f [C,N] = -|w| log P(r_side) with P = sigmoid(log-odds); 0 where nearly edge-on (Eq. 21).
    `weighted=False` (an ablation) drops the |w| factor."""
    return side_values(w, F.softplus(-reliability), w_min, weighted)  # softplus(-l) = -log sigmoid(l)


@torch.no_grad()
def score_candidates(splats: dict[str, torch.Tensor], reliability: torch.Tensor, T_wc: torch.Tensor,
                     K: torch.Tensor, width: int, height: int, *, w_min: float, near: float, far: float,
                     prior: str = "one", chunk: int = 64, backend: str = "auto", weighted: bool = True,
                     one_sided: bool = False, gain_floor: float = 0.0,
                     offset: torch.Tensor | None = None) -> torch.Tensor:
    """Expected MI [C] of candidate camera poses T_wc [C,4,4] rendered with K at width x height.
    Ablations (see reliability.update_from_frame): `weighted=False`, `one_sided=True`. `offset` [C]
    (float64) is a per-candidate term added to the MI (gaussmi2d_explore's frontier gain); the cut
    below ranks the sums with it, so the argmax stays exact for the total.

    With prior "one" the MI is the pixel sum of the sided gain (render.sided_feature_sums). With
    `gain_floor` > 0 a first pass stops each pixel where what is left behind it can add less than
    the floor (render.sided_feature_sums), which gives each candidate's MI within [lower, lower + bound]; the candidates whose
    upper end reaches the best lower end are scored again exactly. Those keep their exact MI, the
    others their lower bound, so the argmax is the exact argmax."""
    C = T_wc.shape[0]
    extra = torch.zeros(C, dtype=torch.float64) if offset is None else offset.double().cpu()
    if C == 0 or splats["means"].shape[0] == 0:
        return extra
    if prior == "depth_noise":
        return extra + _score_with_depth_prior(splats, reliability, T_wc, K, width, height, w_min=w_min,
                                               near=near, far=far, chunk=chunk, backend=backend,
                                               weighted=weighted, one_sided=one_sided).cpu()
    neg_log_p = F.softplus(-reliability)  # -log sigmoid(l): the gain of each side before |w|
    sided = neg_log_p[:, :1].expand(-1, 2).contiguous() if one_sided else neg_log_p
    viewmats = torch.linalg.inv(T_wc)
    Ks = K[None].expand(C, 3, 3).contiguous()

    def sums(idx: torch.Tensor, floor: float):
        return sided_feature_sums(splats["means"], splats["quats"], splats["log_scales"],
                                  splats["opacity_logits"], sided, viewmats[idx], Ks[idx], width, height, near,
                                  far, w_min=w_min, weighted=weighted, floor=floor, backend=backend, chunk=chunk)

    everyone = torch.arange(C)
    first = sums(everyone, gain_floor)
    scores = first.sums.double().cpu() + extra
    if gain_floor > 0 and bool((first.bound > 0).any()):
        contenders = can_still_win(first, extra)
        scores[contenders] = sums(contenders, 0.0).sums.double().cpu() + extra[contenders]
    return scores


def can_still_win(first: FeatureSums, offset: torch.Tensor | None = None) -> torch.Tensor:
    """Indices of the candidates whose upper bound reaches the best lower bound of a cut pass
    (with a per-candidate `offset` added to both bounds)."""
    lower = first.sums.double().cpu() + (0.0 if offset is None else offset)
    return torch.nonzero(lower + first.bound.double().cpu() >= lower.max(), as_tuple=True)[0]


def _score_with_depth_prior(splats, reliability, T_wc, K, width, height, *, w_min, near, far, chunk, backend,
                            weighted, one_sided) -> torch.Tensor:
    """The MI weighted per pixel by the depth-noise prior: needs the rendered depth, so full renders."""
    normals = splat_normals(splats["quats"])

    def gain(poses: torch.Tensor) -> torch.Tensor:
        w = observation_weights(splats["means"], normals, poses[:, :3, 3])
        return information_gain(reliability, w.abs() if one_sided else w, w_min, weighted)[..., None]

    scores = torch.zeros(T_wc.shape[0], dtype=torch.float64)
    for cams, out in render_candidates(splats, gain, T_wc, K, width, height, near=near, far=far,
                                       outputs=("features", "depth"), backend=backend, chunk=chunk):
        img = out.features[..., 0] * depth_noise_prior(out.depth[..., 0])
        scores[cams] = img.double().sum(dim=(1, 2)).cpu()
    return scores
