"""The paper's selector (2D GauSS-MI), its ablations, and random selection: `Selector` plug-ins.

2D GauSS-MI owns the map column it keeps, `reliability` (log-odds [front, back] per splat, Eq. 13),
and answers the stopping statistic from it. The ablations switch one choice of the method each:
`gaussmi2d_now` (no |w| weight in update and gain), `gaussmi2d_onesided` (one reliability per
splat), `gaussmi2d_color` (color-only loss image: lambda_rD = lambda_rNr = 0), `gaussmi2d_edge`
(depth and normal terms left out at occlusion edges of the observed depth: reliability.edge_mask).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from flightrecon.active import gaussmi2d, reliability
from flightrecon.active.diagnosis import mi_split
from flightrecon.active.protocol import (MapView, Observation, Selector, capture_view, observation_tensors,
                                         scoring_intrinsics)
from flightrecon.active.reliability import ReliabilityConfig
from flightrecon.config import ScenarioConfig

RELIABLE_LOGODDS = math.log(0.7 / 0.3)  # a side counts as reliable at P(r) > 0.7 (GauSS-MI's stopping rule)


class GaussMI2D(Selector):
    """The paper's method: two-sided reliability (Eq. 13) and 2D GauSS-MI (Eq. 22)."""

    name = "gaussmi2d"
    section, settings = "reliability", ReliabilityConfig
    COLUMN = "reliability"
    columns = {COLUMN: (2,)}  # log-odds [front, back] per splat
    weighted = True  # ablation switches, set by the variants below
    one_sided = False

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.K_score = scoring_intrinsics(cfg)

    def reliability(self, view: MapView) -> torch.Tensor:
        """The map's two-sided log-odds [N,2]."""
        return view.column(self.COLUMN)

    def observe(self, view: MapView, obs: Observation) -> dict:
        rgb, depth, T_wc, K = observation_tensors(obs, view.device)
        rel = self.reliability(view)
        new, diag = reliability.update_from_frame(
            capture_view(view, obs), view.splats(), rel, rgb, depth, T_wc, K, self.cfg.reliability,
            ssim_weight=self.cfg.mapper.ssim_weight, weighted=self.weighted, one_sided=self.one_sided)
        rel[:] = new
        return diag

    def mutual_information(self, view: MapView, poses: np.ndarray,
                           offset: torch.Tensor | None = None) -> torch.Tensor:
        """2D GauSS-MI [C] (float64, CPU) of candidate cameras T_wc [C,4,4], plus `offset` [C] if given."""
        s, r = self.cfg.selector, self.cfg.reliability
        T = torch.as_tensor(np.asarray(poses, np.float32), device=view.device)
        return gaussmi2d.score_candidates(view.splats(), self.reliability(view), T,
                                          self.K_score.to(view.device), s.scoring_width, s.scoring_height,
                                          w_min=r.w_min, near=view.near, far=view.far,
                                          prior="one" if r.measurement_prior == "one" else "depth_noise",
                                          backend=self.cfg.mapper.backend, weighted=self.weighted,
                                          one_sided=self.one_sided, gain_floor=r.gain_floor, offset=offset)

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return self.mutual_information(view, poses).numpy()

    def stopping_statistic(self, view: MapView) -> float:
        """Share of splats whose front side is reliable (P > 0.7)."""
        rel = self.reliability(view)
        return float((rel[:, 0] > RELIABLE_LOGODDS).float().mean()) if len(rel) else 0.0

    def diagnose(self, view: MapView, T_wc: np.ndarray) -> dict:
        """The chosen view's MI split by kind of splat (active/diagnosis.py)."""
        c, r = self.cfg.selector, self.cfg.reliability
        return mi_split(view.splats(), self.reliability(view), torch.as_tensor(T_wc, dtype=torch.float32),
                        self.K_score, c.scoring_width, c.scoring_height, w_min=r.w_min, clamp=r.logodds_clamp,
                        near=view.near, far=view.far, backend=self.cfg.mapper.backend)


class GaussMI2DNoWeight(GaussMI2D):
    """Ablation: no |w| weight in the reliability update and the gain."""

    name, role = "gaussmi2d_now", "ablation"
    weighted = False


class GaussMI2DOneSided(GaussMI2D):
    """Ablation: one reliability per splat instead of front and back."""

    name, role = "gaussmi2d_onesided", "ablation"
    one_sided = True


class GaussMI2DColorOnly(GaussMI2D):
    """Ablation: the color term alone in the loss image (lambda_rD = lambda_rNr = 0)."""

    name, role = "gaussmi2d_color", "ablation"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg.with_section("reliability", lambda_rD=0.0, lambda_rNr=0.0))


class GaussMI2DEdgeMask(GaussMI2D):
    """Ablation: depth and normal terms left out at occlusion edges of the observed depth."""

    name, role = "gaussmi2d_edge", "ablation"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg.with_section("reliability", edge_mask=True))


class RandomSelector(Selector):
    """Uniformly random among the feasible candidates (seeded): the floor every method must beat."""

    name, role = "random", "floor"

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.rng = np.random.default_rng([cfg.seed, 104729])

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return self.rng.random(len(poses))

    def get_state(self) -> dict:
        return {"rng": self.rng.bit_generator.state}

    def set_state(self, state: dict) -> None:
        self.rng.bit_generator.state = state["rng"]
