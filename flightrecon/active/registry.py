"""Selectors by name: the built-in ones, those other packages register, and those a script registers.

Another package makes its selector available to `fly`, `sweep` and the report by naming the class
under the `flightrecon.selectors` entry point of its own pyproject.toml (docs/selectors.md):

    [project.entry-points."flightrecon.selectors"]
    my_method = "my_package.my_module:MyMethod"

The registry sits above the plug-ins (they import only `active.protocol`), so adding one never
creates an import circle. Entry points are read once, on first use; one that cannot be imported is
reported by name and left out, so a broken plug-in does not take the others down.
"""

from __future__ import annotations

import logging
from importlib.metadata import entry_points

from flightrecon.active.activegs_native import ActiveGSNative
from flightrecon.active.baselines import ActiveGSSelector, FisherRFSelector, GaussMISelector
from flightrecon.active.explore import GaussMI2DExplore
from flightrecon.active.frontier_mi import GaussMI2DFrontier
from flightrecon.active.lookahead import GaussMI2DLookahead
from flightrecon.active.protocol import Selector
from flightrecon.active.selectors import (GaussMI2D, GaussMI2DColorOnly, GaussMI2DEdgeMask, GaussMI2DNoWeight,
                                          GaussMI2DOneSided, RandomSelector)
from flightrecon.config import ScenarioConfig
from flightrecon.errors import ConfigError

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "flightrecon.selectors"
ROLES = ("method", "baseline", "floor", "ablation")
BUILT_IN: tuple[type[Selector], ...] = (GaussMI2D, GaussMI2DExplore, GaussMI2DLookahead, GaussMI2DFrontier,
                                        GaussMISelector, FisherRFSelector, ActiveGSSelector, ActiveGSNative, RandomSelector,
                                        GaussMI2DNoWeight, GaussMI2DOneSided, GaussMI2DColorOnly, GaussMI2DEdgeMask)
_SELECTORS: dict[str, type[Selector]] = {}
_PLUGIN_ERRORS: dict[str, str] = {}  # entry point -> why it was left out
_loaded = False  # built-ins and entry points registered


def register(cls: type[Selector]) -> type[Selector]:
    """Make `selector.method = cls.name` fly `cls` (also usable as a class decorator). A clear error for
    a class that is not a Selector, has no name, an unknown role, or a section another selector
    declares with different settings."""
    selectors()  # the built-ins first, so a script's class is checked against them
    where = f"selector class {getattr(cls, '__module__', '?')}.{getattr(cls, '__qualname__', cls)!s}"
    if not (isinstance(cls, type) and issubclass(cls, Selector)):
        raise ConfigError(f"{where} is not a subclass of flightrecon.Selector")
    if not cls.name or not cls.name.isidentifier():
        raise ConfigError(f"{where}: `name` must be a non-empty identifier, got {cls.name!r}")
    if cls.role not in ROLES:
        raise ConfigError(f"{where}: `role` {cls.role!r} is not one of {', '.join(ROLES)}")
    if (cls.section is None) != (cls.settings is None):
        raise ConfigError(f"{where}: `section` and `settings` go together (both set, or neither)")
    builtin_keys = {f for f in ScenarioConfig.__dataclass_fields__}
    if cls.section in builtin_keys:
        raise ConfigError(f"{where}: section {cls.section!r} is a built-in config section; choose another name")
    for other in _SELECTORS.values():
        if cls.section is not None and other.section == cls.section and other.settings is not cls.settings:
            raise ConfigError(f"{where}: section [{cls.section}] is already declared by selector {other.name!r} "
                              "with other settings; choose another section name")
    _SELECTORS[cls.name] = cls
    return cls


def _load_entry_points() -> None:
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _SELECTORS or ep.name in _PLUGIN_ERRORS:
            continue
        try:
            cls = ep.load()
            if getattr(cls, "name", None) != ep.name:
                raise ConfigError(f"its class names itself {getattr(cls, 'name', None)!r}; the entry point's name "
                                  "and the class's `name` must agree")
            register(cls)
        except Exception as exc:  # a plug-in's import can fail in any way; report it, keep the others
            _PLUGIN_ERRORS[ep.name] = f"{ep.value}: {type(exc).__name__}: {exc}"
            log.warning("selector plug-in %r (entry point %s) left out: %s", ep.name, ep.value, exc)


def selectors() -> dict[str, type[Selector]]:
    """Every available selector class by name: built-in, then from entry points (loaded once)."""
    global _loaded
    if not _loaded:
        _loaded = True
        for cls in BUILT_IN:
            register(cls)
        _load_entry_points()
    return dict(_SELECTORS)


def plugin_errors() -> dict[str, str]:
    """Entry points that could not be loaded, with why (`flightrecon selectors` shows them)."""
    selectors()
    return dict(_PLUGIN_ERRORS)


def config_sections() -> dict[str, type]:
    """The selectors' own config sections: name -> settings dataclass."""
    return {cls.section: cls.settings for cls in selectors().values() if cls.section is not None}


def check_method(name: str, key: str = "selector.method") -> None:
    """A ConfigError naming `key` and the available methods if `name` is not registered."""
    available = selectors()
    if name not in available:
        hint = f"; plug-ins left out: {_PLUGIN_ERRORS}" if _PLUGIN_ERRORS else ""
        raise ConfigError(f"config key {key!r}: unknown method {name!r} (available: {', '.join(sorted(available))})"
                          f"{hint}")


def make_selector(cfg: ScenarioConfig) -> Selector:
    """The selector named by `selector.method`; an unknown name is a config error naming the key."""
    check_method(cfg.selector.method)
    return selectors()[cfg.selector.method](cfg)


def methods_with_role(*roles: str) -> list[str]:
    """Registered selector names whose role is one of `roles`, in registration order."""
    return [name for name, cls in selectors().items() if cls.role in roles]


def role_of(name: str) -> str:
    """The role of the selector named `name`; "method" for a name not registered here (the results of
    a plug-in that is not installed: plug-ins are methods unless they say otherwise)."""
    cls = selectors().get(name)
    return cls.role if cls is not None else "method"


def proposes_own_candidates(name: str) -> bool:
    """Whether the selector named `name` chooses among its own candidates (overrides `propose`);
    False for a name not registered here (results of a plug-in that is not installed)."""
    cls = selectors().get(name)
    return cls is not None and cls.propose is not Selector.propose
