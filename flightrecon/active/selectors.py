"""The paper's selector (2D GauSS-MI), its ablations, and random selection: `Selector` plug-ins.

2D GauSS-MI owns the map column it keeps, `reliability` (log-odds [front, back] per splat, Eq. 13),
and answers the stopping statistic from it. The ablations switch one choice of the method each:
`gaussmi2d_now` (no |w| weight in update and gain), `gaussmi2d_onesided` (one reliability per
splat), `gaussmi2d_color` (color-only loss image: lambda_rD = lambda_rNr = 0), `gaussmi2d_edge`
(depth and normal terms left out at occlusion edges of the observed depth: reliability.edge_mask).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from flightrecon.active import gaussmi2d, reliability
from flightrecon.active.protocol import (Observation, capture_view, ensure_column, observation_tensors,
                                         scoring_intrinsics)
from flightrecon.config import ScenarioConfig
from flightrecon.mapping.mapper import OnlineMapper

RELIABLE_LOGODDS = math.log(0.7 / 0.3)  # a side counts as reliable at P(r) > 0.7 (GauSS-MI's stopping rule)


class GaussMI2D:
    """The paper's method: two-sided reliability (Eq. 13) and 2D GauSS-MI (Eq. 22)."""

    name = "gaussmi2d"
    COLUMN = "reliability"
    weighted = True  # ablation switches, set by the variants below
    one_sided = False

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.cfg = cfg
        self.K_score = scoring_intrinsics(cfg)

    def reliability(self, mapper: OnlineMapper) -> torch.Tensor:
        """The map's two-sided log-odds [N,2] (a column this selector adds to the map)."""
        return ensure_column(mapper, self.COLUMN, (2,))

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        rgb, depth, T_wc, K = observation_tensors(obs, mapper.device)
        rel = self.reliability(mapper)
        new, diag = reliability.update_from_frame(
            capture_view(mapper, obs), mapper.splats(), rel, rgb, depth, T_wc, K, self.cfg.reliability,
            ssim_weight=self.cfg.mapper.ssim_weight, weighted=self.weighted, one_sided=self.one_sided)
        rel[:] = new
        return diag

    def mutual_information(self, mapper: OnlineMapper, poses: np.ndarray,
                           offset: torch.Tensor | None = None) -> torch.Tensor:
        """2D GauSS-MI [C] (float64, CPU) of candidate cameras T_wc [C,4,4], plus `offset` [C] if given."""
        s = self.cfg.selector
        T = torch.as_tensor(np.asarray(poses, np.float32), device=mapper.device)
        return gaussmi2d.score_candidates(mapper.splats(), self.reliability(mapper), T,
                                          self.K_score.to(mapper.device), s.scoring_width, s.scoring_height,
                                          w_min=self.cfg.reliability.w_min, near=mapper.near, far=mapper.far,
                                          prior="one" if s.measurement_prior == "one" else "depth_noise",
                                          backend=self.cfg.mapper.backend, weighted=self.weighted,
                                          one_sided=self.one_sided, gain_floor=s.gain_floor, offset=offset)

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return self.mutual_information(mapper, poses).numpy()

    def reliable_share(self, mapper: OnlineMapper) -> float:
        """Share of splats whose front side is reliable (P > 0.7)."""
        rel = self.reliability(mapper)
        return float((rel[:, 0] > RELIABLE_LOGODDS).float().mean()) if len(rel) else 0.0


class GaussMI2DNoWeight(GaussMI2D):
    name = "gaussmi2d_now"
    weighted = False


class GaussMI2DOneSided(GaussMI2D):
    name = "gaussmi2d_onesided"
    one_sided = True


class GaussMI2DColorOnly(GaussMI2D):
    name = "gaussmi2d_color"

    def __init__(self, cfg: ScenarioConfig) -> None:
        color_only = dataclasses.replace(cfg.reliability, lambda_rD=0.0, lambda_rNr=0.0)
        super().__init__(dataclasses.replace(cfg, reliability=color_only))


class GaussMI2DEdgeMask(GaussMI2D):
    name = "gaussmi2d_edge"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(dataclasses.replace(cfg, reliability=dataclasses.replace(cfg.reliability, edge_mask=True)))


class RandomSelector:
    """Uniformly random among the feasible candidates (seeded): the floor every method must beat."""

    name = "random"

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.rng = np.random.default_rng([cfg.seed, 104729])

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        return {}

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return self.rng.random(len(poses))

    def reliable_share(self, mapper: OnlineMapper) -> float:
        return 0.0
