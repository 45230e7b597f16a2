"""Why a view was chosen: the chosen candidate's 2D GauSS-MI split by the kind of splat it comes
from, and the kind of move that reaches it.

Kinds, by the log-odds l of the side the candidate would observe (Eq. 12): `back_unseen` (back
side, never updated: l = 0 exactly), `back_seen`, `front_unseen` (front side never updated: a
splat no view has updated yet), `negative` (l < 0: observed and found wrong), `weak` (0 < l < 5),
`strong` (5 <= l < clamp), `clamped` (l at the clamp). The split is one render of the candidate
with one feature channel per kind (the gain masked to the kind), so the parts sum to the MI; the
share of the MI on pixels at occlusion edges of the rendered depth is reported too.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from flightrecon.active.gaussmi2d import information_gain
from flightrecon.active.reliability import (BACK, FRONT, depth_edges, observation_weights, observed_side,
                                           splat_normals)
from flightrecon.render import render

KINDS = ("back_unseen", "back_seen", "front_unseen", "negative", "weak", "strong", "clamped")
STRONG = 5.0  # log-odds from which a side counts as strongly reliable (P > 0.993)


def splat_kinds(w: torch.Tensor, reliability: torch.Tensor, w_min: float, clamp: float) -> torch.Tensor:
    """Kind index [N] (into KINDS) of the side each splat shows at cosines w [N]; -1 when edge-on."""
    side = observed_side(w, w_min)
    idx = torch.arange(len(w), device=w.device)
    l_obs = reliability[idx, side.clamp_min(0)]
    kind = torch.full_like(side, -1)
    back, front = side == BACK, side == FRONT
    kind[back] = torch.where(l_obs[back] == 0, 0, 1)
    f = l_obs[front]
    kind[front] = torch.where(f == 0, 2, torch.where(f < 0, 3, torch.where(f < STRONG, 4, torch.where(
        f < clamp - 1e-3, 5, 6))))
    return kind


@torch.no_grad()
def mi_split(splats: dict[str, torch.Tensor], reliability: torch.Tensor, T_wc: torch.Tensor, K: torch.Tensor,
             width: int, height: int, *, w_min: float, clamp: float, near: float, far: float,
             backend: str = "auto") -> dict[str, float]:
    """The MI of one candidate (T_wc [4,4]) by kind (`mi_<kind>`), in total (`mi`), the share of it
    on occlusion-edge pixels (`mi_edge_share`) and those pixels' share of the image."""
    normals = splat_normals(splats["quats"])
    w = observation_weights(splats["means"], normals, T_wc[None, :3, 3])[0]
    kind = splat_kinds(w, reliability, w_min, clamp)
    gain = information_gain(reliability, w[None], w_min)[0]  # Eq. 21
    onehot = F.one_hot(kind.clamp_min(0), len(KINDS)).to(gain.dtype) * (kind >= 0)[:, None]
    out = render(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"],
                 gain[:, None] * onehot, torch.linalg.inv(T_wc)[None], K[None], width, height, near=near, far=far,
                 outputs=("features", "depth"), backend=backend)
    img = out.features[0].double()  # [H,W,kinds]
    total = float(img.sum())
    edge = depth_edges(out.depth[0, ..., 0])
    row = {f"mi_{k}": float(img[..., i].sum()) for i, k in enumerate(KINDS)}
    row["mi"] = total
    row["mi_edge_share"] = float(img[edge].sum()) / total if total > 0 else math.nan
    row["edge_pixel_share"] = float(edge.double().mean())
    return row


def move_kind(p0: np.ndarray, yaw0: float, p1: np.ndarray, yaw1: float, step: float = 0.1,
              turn_deg: float = 10.0) -> str:
    """'stay' (moves < step m and turns < turn_deg), 'turn' (turns only) or 'step' (moves)."""
    moved = float(np.linalg.norm(np.asarray(p1) - np.asarray(p0))) >= step
    dyaw = abs((yaw1 - yaw0 + math.pi) % (2 * math.pi) - math.pi)
    if moved:
        return "step"
    return "turn" if dyaw >= math.radians(turn_deg) else "stay"
