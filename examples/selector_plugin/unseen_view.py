"""`unseen_view`: a view-selection method written outside FlightRecon, as one file.

Score of a candidate view: the share of its pixels where the map shows no surface yet (rendered
opacity below one half), minus `path_weight` times the planned path length in metres. It keeps one
map column, how many captured frames each splat was seen in, and answers the stopping statistic
from it (the share of splats seen at least `seen_enough` times). Everything it needs comes from
the public API: `flightrecon.Selector`, `MapView`, `Observation` and `option`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from flightrecon import MapView, Observation, Selector, option


@dataclass(frozen=True)
class UnseenViewConfig:
    """`[unseen_view]` in a scenario file, or `--set unseen_view.path_weight=0.1`."""

    width: int = option(32, 4, 1024, doc="scoring render width (pixels)")
    height: int = option(24, 3, 768, doc="scoring render height (pixels)")
    path_weight: float = option(0.05, 0.0, 10.0, doc="score lost per metre of planned path")
    seen_enough: int = option(3, 1, 1000, doc="frames a splat must be seen in to count for the stopping statistic")


class UnseenView(Selector):
    """Fly to where the map shows least (an example plug-in)."""

    name = "unseen_view"
    section, settings = "unseen_view", UnseenViewConfig
    columns = {"times_seen": ()}

    def _intrinsics(self) -> np.ndarray:
        c, s = self.cfg.camera, self.cfg.unseen_view
        f = 0.5 * s.width / np.tan(np.radians(c.hfov_deg) / 2)
        return np.array([[f, 0, s.width / 2], [0, f, s.height / 2], [0, 0, 1.0]])

    def observe(self, view: MapView, obs: Observation) -> dict:
        if len(view) == 0:
            return {}
        H, W = obs.depth.shape
        rendered = obs.view if obs.view is not None else view.render(obs.T_wc, obs.K, W, H)
        seen = rendered.splat_sums(torch.ones(H, W, device=view.device)) > 0.5
        view.column("times_seen")[seen] += 1
        return {"seen": int(seen.sum())}

    def unseen_share(self, view: MapView, T_wc: np.ndarray) -> float:
        s = self.cfg.unseen_view
        if len(view) == 0:
            return 1.0
        alpha = view.render(T_wc, self._intrinsics(), s.width, s.height).output.alpha
        return float((alpha < 0.5).float().mean())

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        unseen = np.array([self.unseen_share(view, T) for T in poses])
        path = np.zeros(len(poses)) if lengths is None else np.asarray(lengths, float)
        return unseen - self.cfg.unseen_view.path_weight * path

    def stopping_statistic(self, view: MapView) -> float:
        seen = view.column("times_seen")
        return float((seen >= self.cfg.unseen_view.seen_enough).float().mean()) if len(seen) else 0.0

    def diagnose(self, view: MapView, T_wc: np.ndarray) -> dict:
        return {"unseen_share": self.unseen_share(view, T_wc)}
