"""Selectors by name: the built-in plug-ins and any a user registers.

The registry sits above the plug-ins (they import only `active.protocol`), so adding a selector
never creates an import circle: write a class with `name`, `observe`, `score` and `reliable_share`,
and either add it to BUILT_IN or call `register` before the loop starts.
"""

from __future__ import annotations

from typing import Callable

from flightrecon.active.activegs_native import ActiveGSNative
from flightrecon.active.baselines import ActiveGSSelector, FisherRFSelector, GaussMISelector
from flightrecon.active.explore import GaussMI2DExplore
from flightrecon.active.protocol import Selector
from flightrecon.active.selectors import (GaussMI2D, GaussMI2DColorOnly, GaussMI2DEdgeMask, GaussMI2DNoWeight,
                                          GaussMI2DOneSided, RandomSelector)
from flightrecon.config import ScenarioConfig
from flightrecon.errors import ConfigError

Factory = Callable[[ScenarioConfig], Selector]
BUILT_IN: tuple[type, ...] = (GaussMI2D, GaussMI2DExplore, GaussMISelector, FisherRFSelector, ActiveGSSelector,
                              ActiveGSNative, RandomSelector, GaussMI2DNoWeight, GaussMI2DOneSided, GaussMI2DColorOnly,
                              GaussMI2DEdgeMask)
SELECTORS: dict[str, Factory] = {cls.name: cls for cls in BUILT_IN}


def register(name: str, factory: Factory) -> None:
    """Make `selector.method = name` build the selector with `factory(cfg)`."""
    SELECTORS[name] = factory


def check_method(name: str, key: str = "selector.method") -> None:
    """A ConfigError naming `key` and the available methods if `name` is not registered."""
    if name not in SELECTORS:
        raise ConfigError(f"config key {key!r}: unknown method {name!r} (available: {', '.join(sorted(SELECTORS))})")


def make_selector(cfg: ScenarioConfig) -> Selector:
    """The selector named by `selector.method`; an unknown name is a config error naming the key."""
    check_method(cfg.selector.method)
    return SELECTORS[cfg.selector.method](cfg)
