"""`sided_feature_sums(...)`: per camera, the pixel sum of a rendered one-channel feature that each
splat takes from the side the camera sees, optionally cut short where only small values remain.

A splat carries two values (front: the side its normal points to; back). Camera c sees the front
when w = n . (o_c - mu) / |o_c - mu| > w_min, the back when w < -w_min, neither when nearly
edge-on; with `weighted` the value is scaled by |w|. The sum over pixels of the image rendered
with these per-camera features is what a view-selection criterion of the form
sum_j sum_i f_i T^[i,j] needs (2D GauSS-MI's MI, docs/equations.md), without the [C,N] feature
tensor or the [C,H,W] images.

`floor` > 0 trades exactness for speed with a guaranteed bound: a pixel stops before a splat of
its 16x16 tile's depth-sorted list once its transmittance times the largest value from there to
the list's end is below `floor`; values are >= 0 and what follows weighs at most that
transmittance. The result holds sums <= exact <= sums + bound per camera (bound = the sum of those
products over the stopped pixels, under `floor` each). Only the cpu backend cuts; the others render exactly
(bound 0) through `render`, which is also the torch twin the tests hold the kernel to.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from flightrecon.errors import DataError, FlightReconError
from flightrecon.render.api import all_finite, check_inputs, render, resolve_backend


@dataclass
class FeatureSums:
    """sums [C] float64 and bound [C] float64: the exact sum lies in [sums, sums + bound]."""

    sums: Tensor
    bound: Tensor


def view_cosines(means: Tensor, normals: Tensor, centers: Tensor) -> Tensor:
    """w [C,N] = n_i . (o_c - mu_i) / |o_c - mu_i| for unit normals [N,3] and camera centers [C,3]."""
    d = torch.nn.functional.normalize(centers[:, None, :] - means[None], dim=-1)
    return (d * normals[None]).sum(-1)


def side_values(w: Tensor, sided: Tensor, w_min: float, weighted: bool = True) -> Tensor:
    """Per-camera features [C,N] from cosines w [C,N] and two-sided values [N,2]: the front value where
    w > w_min, the back value where w < -w_min, 0 in between; times |w| when weighted."""
    value = torch.where(w > w_min, sided[None, :, 0], torch.where(w < -w_min, sided[None, :, 1], 0.0))
    return value * w.abs() if weighted else value


def sided_feature_sums(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor, sided: Tensor,
                       viewmats: Tensor, Ks: Tensor, width: int, height: int, near: float = 0.05,
                       far: float = 10.0, *, w_min: float, weighted: bool = True, floor: float = 0.0,
                       backend: str = "auto", chunk: int = 64) -> FeatureSums:
    """Pixel sums [C] of the sided feature rendered into C cameras (viewmats world-to-camera, OpenCV
    axes), with the bound of the cut (see the module docstring). No gradients."""
    C = viewmats.shape[0]
    if sided.dim() != 2 or sided.shape != (means.shape[0], 2):
        raise FlightReconError(f"sided_feature_sums: sided has shape {tuple(sided.shape)}, expected "
                               f"({means.shape[0]}, 2) (front, back per splat)")
    if not all_finite(sided):
        raise DataError("sided_feature_sums: sided contains NaN or inf")
    check_inputs(means, quats, log_scales, opacity_logits, sided, viewmats, Ks, width, height, near, far, ())
    if not floor >= 0.0:
        raise FlightReconError(f"sided_feature_sums: floor must be >= 0, got {floor}")
    if floor > 0 and bool((sided < 0).any()):
        raise FlightReconError("sided_feature_sums: a cut (floor > 0) bounds only sums of values >= 0; sided holds "
                               "negative values: give floor=0")
    zeros = torch.zeros(C, dtype=torch.float64)
    if C == 0 or means.shape[0] == 0:
        return FeatureSums(zeros, zeros.clone())
    with torch.no_grad():
        if resolve_backend(backend) == "cpu" and not means.is_cuda:
            return _sums_cpu(means, quats, log_scales, opacity_logits, sided, viewmats, Ks, width, height, near,
                             far, w_min, weighted, floor)
        return _sums_by_render(means, quats, log_scales, opacity_logits, sided, viewmats, Ks, width, height, near,
                               far, w_min, weighted, backend, chunk)


def _sums_cpu(means, quats, log_scales, opacity_logits, sided, viewmats, Ks, width, height, near, far, w_min,
              weighted, floor) -> FeatureSums:
    from flightrecon.render.backend_cpu import opacity_cpu, splat_axes_cpu
    from flightrecon.render.extension import load

    dt = means.dtype
    U, V, n = splat_axes_cpu(quats, log_scales)
    args = [t.to(dt).contiguous() for t in (means, U, V, n, opacity_cpu(opacity_logits), sided)]
    sums, bound = load().feature_sums(*args, viewmats.double().contiguous(), Ks.double().contiguous(), width,
                                      height, float(near), float(far), float(w_min), bool(weighted), float(floor))
    return FeatureSums(sums, bound)


def _sums_by_render(means, quats, log_scales, opacity_logits, sided, viewmats, Ks, width, height, near, far,
                    w_min, weighted, backend, chunk) -> FeatureSums:
    from flightrecon.render.projection import quat_to_rotmat

    normals = quat_to_rotmat(torch.nn.functional.normalize(quats, dim=-1))[..., 2]
    centers = torch.linalg.inv(viewmats)[:, :3, 3]
    sums = []
    for s in range(0, viewmats.shape[0], chunk):
        f = side_values(view_cosines(means, normals, centers[s:s + chunk]), sided, w_min, weighted)[..., None]
        out = render(means, quats, log_scales, opacity_logits, f, viewmats[s:s + chunk], Ks[s:s + chunk], width,
                     height, near=near, far=far, outputs=("features",), backend=backend)
        sums.append(out.features[..., 0].double().sum(dim=(1, 2)).cpu())
    total = torch.cat(sums)
    return FeatureSums(total, torch.zeros_like(total))
