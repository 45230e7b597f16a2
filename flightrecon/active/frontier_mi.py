"""`gaussmi2d_frontier`: ActiveGS's exploration utility for space no frame has seen, the paper's 2D
GauSS-MI for the splats the map holds (beyond the paper).

The comparison (results/ranking, results/ablations/issue35_library) shows where each criterion pays:
the frontier value of ActiveGS buys coverage, and coverage is most of the PSNR over all pixels; the
paper's MI ranks which of the mapped splats a view would make reliable, but values nothing the map
does not hold yet. This variant keeps ActiveGS's form, U = w U_explore + U_exploit, then
U / sum U - path_weight L / sum L, with ActiveGS's voxel map and exploration term (unexplored voxels
in front of the map's rendered depth), and replaces its surfel-confidence exploitation by the
paper's MI (Eq. 22) of each candidate divided by the largest among the candidates, so that both
exploitation terms lie in [0, 1]. Its settings are its own section, so a sweep that changes
`activegs.*` does not move it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flightrecon.active.baselines import ActiveGSSelector, activegs_combine
from flightrecon.active.protocol import MapView, Observation, Selector
from flightrecon.active.selectors import GaussMI2D
from flightrecon.config import ScenarioConfig, option


@dataclass(frozen=True)
class FrontierMIConfig:
    """`[frontier_mi]`: the weights of gaussmi2d_frontier (its voxel map reads `[activegs]`, its MI
    `[reliability]`)."""

    explore_weight: float = option(1000.0, 0.0, 1e6, doc="weight of the exploration utility against the MI")
    path_weight: float = option(0.5, 0.0, 100.0, doc="path-length term weight")


class GaussMI2DFrontier(Selector):
    """ActiveGS's exploration and path terms around the paper's MI (module docstring)."""

    name = "gaussmi2d_frontier"
    section, settings = "frontier_mi", FrontierMIConfig
    columns = {**ActiveGSSelector.columns, **GaussMI2D.columns}  # ActiveGS's render reads its columns (zero here)

    def __init__(self, cfg: ScenarioConfig) -> None:
        super().__init__(cfg)
        self.space = ActiveGSSelector(cfg)
        self.mi = GaussMI2D(cfg)

    def attach_scene(self, bounds: np.ndarray) -> None:
        self.space.attach_scene(bounds)

    def observe(self, view: MapView, obs: Observation) -> dict:
        self.space.observe_space(obs.depth, obs.K, obs.T_wc)  # its voxel map; ActiveGS's confidence is not used
        return self.mi.observe(view, obs)

    def utilities(self, view: MapView, poses: np.ndarray) -> np.ndarray:
        """U = w U_explore + MI / max MI per candidate (before normalization and path term)."""
        explore, _ = self.space.explore_exploit(view, poses)
        mi = self.mi.mutual_information(view, poses).numpy() if len(view) else np.zeros(len(poses))
        top = mi.max(initial=0.0)
        return self.cfg.frontier_mi.explore_weight * explore + (mi / top if top > 0 else np.zeros_like(mi))

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return activegs_combine(self.utilities(view, poses), self.space.path_lengths(poses, lengths),
                                self.cfg.frontier_mi.path_weight, self.space.rng)

    def stopping_statistic(self, view: MapView) -> float:
        return self.mi.stopping_statistic(view)

    def diagnose(self, view: MapView, T_wc: np.ndarray) -> dict:
        return self.mi.diagnose(view, T_wc)

    def get_state(self) -> dict:
        return self.space.get_state()

    def set_state(self, state: dict) -> None:
        self.space.set_state(state)
