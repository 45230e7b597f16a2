"""What the closed loop and a view selector say to each other: the `Selector` base class, the
observation it is shown after every captured frame, and the narrow view of the map it works on.

A selector is one class in one file (docs/selectors.md): its `name`, optionally its own config
section (`section` and a frozen `settings` dataclass whose fields use `config.option`), the per-splat
map columns it keeps (`columns`), and the calls below. Only `score` is required. All selectors share
the mapper, planner and candidate library of the loop, so comparing them isolates the selection
criterion. Plug-ins import this module only; `active.registry` finds them by name (built-in, or
registered by another package under the `flightrecon.selectors` entry point).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

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


class MapView:
    """What a selector sees of the map: the splats' parameters, the columns it declared, and one render
    call. The mapper's optimizer, frames and voxel hash stay out of reach, so a selector cannot change
    what the map learns, only what it keeps beside it."""

    def __init__(self, mapper: OnlineMapper, columns: dict[str, tuple[int, ...]]) -> None:
        self._mapper = mapper
        self._columns = dict(columns)
        for name, shape in self._columns.items():
            if name not in mapper.map:
                mapper.map.add_column(name, tuple(shape), torch.float32)

    def __len__(self) -> int:
        return len(self._mapper.map)

    @property
    def device(self) -> torch.device:
        return self._mapper.device

    @property
    def near(self) -> float:
        return self._mapper.near

    @property
    def far(self) -> float:
        return self._mapper.far

    def splats(self) -> dict[str, torch.Tensor]:
        """means [N,3], quats [N,4] (unit), log_scales [N,2], opacity_logits [N], colors [N,3]."""
        return self._mapper.splats()

    def column(self, name: str) -> torch.Tensor:
        """The selector's own per-splat column (float32 [N, *shape], zeros for new splats); the map keeps it
        aligned with the splats through growth and pruning, saves it with `output.ply_extras` and in
        checkpoints."""
        if name not in self._columns:
            raise KeyError(f"map column {name!r} was not declared by the selector (declared: "
                           f"{', '.join(self._columns) or 'none'}); add it to the selector's `columns`")
        return self._mapper.map[name]

    def render(self, T_wc: np.ndarray, K: np.ndarray, width: int, height: int) -> RenderedView:
        """The map at camera T_wc (color, alpha, depth, normal), with per-splat pixel sums."""
        return self._mapper.render_capture(T_wc, K, width, height)


class Selector:
    """Base of every view selector; override `score` and whichever optional hooks the method needs."""

    name: ClassVar[str] = ""
    role: ClassVar[str] = "method"  # method | baseline | floor | ablation: what `sweep` flies by default
    # (methods, baselines and the floor) and which the report pairs the others against (methods)
    section: ClassVar[str | None] = None  # the config section of its own settings, `[section]`
    settings: ClassVar[type | None] = None  # frozen dataclass of that section (fields: config.option)
    columns: ClassVar[dict[str, tuple[int, ...]]] = {}  # per-splat map columns it keeps: name -> shape

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.cfg = cfg

    def observe(self, view: MapView, obs: Observation) -> dict:
        """Update the selector's state after `obs` was mapped; returns diagnostics for the logs."""
        return {}

    def score(self, view: MapView, poses: np.ndarray, lengths: np.ndarray | None = None) -> np.ndarray:
        """Scores [C] of candidate camera poses T_wc [C,4,4] reached by planned paths of `lengths` [C] m
        (None: unknown); the loop flies to the argmax."""
        raise NotImplementedError(f"selector {self.name!r} does not implement score()")

    def stopping_statistic(self, view: MapView) -> float | None:
        """Share of the map the selector deems reliable, for the stopping rule (`budget.stop_on_reliability`,
        GauSS-MI's); None for a selector that keeps no such statistic."""
        return None

    def diagnose(self, view: MapView, T_wc: np.ndarray) -> dict:
        """Extra columns of diagnosis.csv (`output.diagnose`) about the chosen camera T_wc [4,4]."""
        return {}

    def attach_scene(self, bounds: np.ndarray) -> None:
        """The scene's bounding box (2,3), once, before the first frame (for a selector that maps the scene)."""

    def propose(self, view: MapView, position: np.ndarray, yaw: float,
                frame: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The selector's own candidate viewpoints for this step, (positions [M,3], yaws [M]), checked by the
        planner instead of the shared library; None: the shared library."""
        return None

    def get_state(self) -> dict[str, Any]:
        """What the selector carries between frames outside its map columns (arrays and JSON values), for
        checkpoints; `set_state` of it continues exactly."""
        return {}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore what `get_state` returned."""


def capture_view(view: MapView, obs: Observation) -> RenderedView:
    """The map rendered at the observation's pose after mapping: the loop's shared render, or a new one
    when the observation came without it (a selector driven outside the loop)."""
    if obs.view is None:
        H, W = np.asarray(obs.depth).shape
        obs.view = view.render(obs.T_wc, obs.K, W, H)
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

