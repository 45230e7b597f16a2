"""What the closed loop and a view selector say to each other: the observation a selector is shown
after every captured frame, and the small `Selector` protocol.

A selector sees the map after every captured frame (`observe`), scores the feasible candidate
views of a step (`score`, higher is better) and answers the share of the map it deems reliable
(`reliable_share`, GauSS-MI's stopping statistic). All selectors share the mapper, planner and
candidate library of the loop, so comparing them isolates the selection criterion. Plug-ins
import this module only; `active.registry` finds them by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from flightrecon.config import ScenarioConfig
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


def scoring_intrinsics(cfg: ScenarioConfig, width: int | None = None, height: int | None = None) -> torch.Tensor:
    """K [3,3] of the config's camera rendered at width x height (default: the selector's scoring
    resolution), with the same field of view."""
    c, s = cfg.camera, cfg.selector
    width, height = width or s.scoring_width, height or s.scoring_height
    K = torch.tensor(intrinsics(c.width, c.height, c.hfov_deg), dtype=torch.float32)
    K[0] *= width / c.width
    K[1] *= height / c.height
    return K


def float_tensor(a, device: torch.device) -> torch.Tensor:
    """An array (poses, images) as a float32 tensor on the map's device."""
    return torch.as_tensor(np.asarray(a, np.float32), device=device)


def observation_tensors(obs: Observation, device: torch.device) -> tuple[torch.Tensor, ...]:
    """(rgb [H,W,3], depth [H,W,1], T_wc [4,4], K [3,3]) of an observation as float32 tensors."""
    return (float_tensor(obs.rgb, device), float_tensor(obs.depth, device)[..., None],
            float_tensor(obs.T_wc, device), float_tensor(obs.K, device))


def ensure_column(mapper: OnlineMapper, name: str, shape: tuple[int, ...]) -> torch.Tensor:
    """The selector's own per-splat column `name` of the map, added (zeros) on first use; the map keeps
    it aligned with the splats through growth and pruning."""
    if name not in mapper.map:
        mapper.map.add_column(name, shape, torch.float32)
    return mapper.map[name]


class Selector(Protocol):
    name: str

    def observe(self, mapper: OnlineMapper, obs: Observation) -> dict:
        """Update the selector's state after `obs` was mapped; returns diagnostics for the logs."""

    def score(self, mapper: OnlineMapper, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        """Scores [C] of candidate camera poses T_wc [C,4,4] reached by planned paths of `lengths` [C] m
        (None: unknown); the loop flies to the argmax."""

    def reliable_share(self, mapper: OnlineMapper) -> float:
        """Share of the map's splats the selector deems reliable (the loop's stopping statistic);
        0 for a selector that keeps no reliability, so the stopping rule never stops it."""

    # Optional, called by the loop when a selector has them:
    #   attach_scene(bounds (2,3)): the scene's bounding box, once, before the first frame.
    #   propose(mapper, position (3,), yaw, frame) -> (positions [M,3], yaws [M]): the selector's own
    #       candidate viewpoints for this step, checked by the planner instead of the shared library.
