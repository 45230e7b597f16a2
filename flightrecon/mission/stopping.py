"""GauSS-MI's stopping rule: stop once the map is reliable enough (`budget.stop_on_reliability`).

The statistic is the selector's (`Selector.stopping_statistic`: for 2D GauSS-MI, the share of splats
whose reliability passes its threshold); the loop keeps an exponential moving average of it over
frames and stops once that average passes RELIABLE_STOP. A selector without the statistic cannot
use the rule: asking for it is a config error, not a flight that never stops.
"""

from __future__ import annotations

import math

from flightrecon.active.protocol import MapView, Selector
from flightrecon.config import ScenarioConfig
from flightrecon.errors import ConfigError
from flightrecon.mission.state import MissionState

RELIABLE_EMA, RELIABLE_STOP = 0.95, 0.75


def has_stopping_statistic(selector: Selector) -> bool:
    """Whether the selector overrides `stopping_statistic` (the base class keeps none)."""
    return type(selector).stopping_statistic is not Selector.stopping_statistic


def check_rule_allowed(cfg: ScenarioConfig, selector: Selector) -> None:
    """A ConfigError naming `budget.stop_on_reliability` when it is on for a selector without the statistic."""
    if cfg.budget.stop_on_reliability and not has_stopping_statistic(selector):
        raise ConfigError(f"config key 'budget.stop_on_reliability': selector {cfg.selector.method!r} keeps no "
                          "stopping statistic; set it to false or choose a selector that has one")


def update(selector: Selector, view: MapView, state: MissionState) -> float:
    """Fold this frame's share of reliable splats into the state's moving average (0.95) and return
    the average (frames.csv's `reliable_share_ema`); NaN, and the average untouched, for a selector
    without the statistic."""
    share = selector.stopping_statistic(view)
    if share is None:
        return math.nan
    state.reliable_ema = RELIABLE_EMA * state.reliable_ema + (1 - RELIABLE_EMA) * share
    return state.reliable_ema


def rule_met(cfg: ScenarioConfig, average: float) -> bool:
    """`budget.stop_on_reliability` is on and the average has passed RELIABLE_STOP."""
    return cfg.budget.stop_on_reliability and average > RELIABLE_STOP


def stop_text(frame: int, average: float) -> str:
    """The events.log line of a flight the rule ended after `frame`."""
    return f"frame {frame}: stopping rule met (EMA of the reliable share {average:.3f} > {RELIABLE_STOP})"
