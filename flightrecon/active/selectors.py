"""View-selector plug-ins: the small protocol the closed loop talks to, and the registry by name.

A selector sees the map after every captured frame (`observe`) and scores the feasible candidate
views of a step (`score`, higher is better). All selectors share the mapper, planner and candidate
library of the loop, so comparing them isolates the selection criterion. New selectors (the
evaluation baselines) register themselves with `register`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np
import torch

from flightrecon.active import gaussmi2d, reliability
from flightrecon.config import ScenarioConfig
from flightrecon.errors import ConfigError
from flightrecon.geometry import intrinsics
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.render import RenderedView


@dataclass
class Observation:
    """One captured frame as the selectors see it (OpenCV camera-to-world pose)."""

    index: int
    rgb: np.ndarray  # (H, W, 3) float32
    depth: np.ndarray  # (H, W) float32, 0 invalid
    K: np.ndarray
    T_wc: np.ndarray
    view: RenderedView | None = None  # the map rendered at T_wc after mapping (the loop sets it)


def capture_view(mapper: OnlineMapper, obs: Observation) -> RenderedView:
    """The map rendered at the observation's pose after mapping: the loop's shared render, or a new one
    when the observation came without it (a selector driven outside the loop)."""
    if obs.view is None:
        H, W = np.asarray(obs.depth).shape
        obs.view = mapper.render_capture(obs.T_wc, obs.K, W, H)
    return obs.view


class Selector(Protocol):
    name: str

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        """Update the selector's state after `obs` was mapped; returns diagnostics for the logs."""

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        """Scores [C] of candidate camera poses T_wc [C,4,4] reached by planned paths of `lengths` [C] m
        (None: unknown); the loop flies to the argmax."""


def splats_of(mapper: OnlineMapper) -> dict[str, torch.Tensor]:
    """The map's current splat parameters (unit quaternions), as the renderer takes them."""
    return mapper.splats()


class GaussMI2D:
    """The paper's method: two-sided reliability (Eq. 13) and 2D GauSS-MI (Eq. 22)."""

    name = "gaussmi2d"
    weighted = True  # ablation switches, set by the variants in active.baselines
    one_sided = False

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.cfg = cfg
        c = cfg.camera
        s = cfg.selector
        K = torch.tensor(intrinsics(c.width, c.height, c.hfov_deg), dtype=torch.float32)
        self.K_score = gaussmi2d.scoring_intrinsics(K, c.width, c.height, s.scoring_width, s.scoring_height)

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        dev = mapper.device
        t = lambda a: torch.as_tensor(np.asarray(a, np.float32), device=dev)  # noqa: E731
        new, diag = reliability.update_from_frame(
            capture_view(mapper, obs), splats_of(mapper), mapper.map["reliability"], t(obs.rgb),
            t(obs.depth)[..., None], t(obs.T_wc), t(obs.K), self.cfg.reliability,
            ssim_weight=self.cfg.mapper.ssim_weight, weighted=self.weighted, one_sided=self.one_sided)
        mapper.map["reliability"][:] = new
        return diag

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        s = self.cfg.selector
        T = torch.as_tensor(np.asarray(poses, np.float32), device=mapper.device)
        mi = gaussmi2d.score_candidates(splats_of(mapper), mapper.map["reliability"], T,
                                        self.K_score.to(mapper.device), s.scoring_width, s.scoring_height,
                                        w_min=self.cfg.reliability.w_min, near=mapper.near, far=mapper.far,
                                        prior="one" if s.measurement_prior == "one" else "depth_noise",
                                        backend=self.cfg.mapper.backend, weighted=self.weighted,
                                        one_sided=self.one_sided, gain_floor=s.gain_floor)
        return mi.cpu().numpy()


class RandomSelector:
    """Uniformly random among the feasible candidates (seeded): the floor every method must beat."""

    name = "random"

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.rng = np.random.default_rng([cfg.seed, 104729])

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        return {}

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        return self.rng.random(len(poses))


SELECTORS: dict[str, Callable[[ScenarioConfig], Selector]] = {"gaussmi2d": GaussMI2D, "random": RandomSelector}


def register(name: str, factory: Callable[[ScenarioConfig], Selector]) -> None:
    SELECTORS[name] = factory


def make_selector(cfg: ScenarioConfig) -> Selector:
    """The selector named by `selector.method`; an unknown name is a config error naming the key."""
    name = cfg.selector.method
    if name not in SELECTORS:
        raise ConfigError(f"config key 'selector.method': unknown method {name!r} "
                          f"(available: {', '.join(sorted(SELECTORS))})")
    return SELECTORS[name](cfg)


from flightrecon.active import baselines  # noqa: E402,F401  (registers the baselines and ablations)
