"""A scenario as flights, sweeps and scripts load it: config.py's built-in sections and the selectors'
own (`[reliability]`, `[activegs]`, ...), every key validated.

config.py is the schema and knows no selector; the registry (active/registry.py) knows which
sections the registered selectors declare, and imports config.py for their types. Loading needs
both, so it lives here, above them: neither has to import the other's layer.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from flightrecon.active.registry import config_sections
from flightrecon.config import ScenarioConfig, from_table, read_scenario
from flightrecon.errors import ConfigError


def load_config(source: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> ScenarioConfig:
    """Load a scenario TOML (or the defaults when `source` is None), apply overrides, validate."""
    return _build_scenario(read_scenario(source, overrides))


def _move_renamed_keys(data: dict, types: dict[str, type]) -> dict:
    """Keys a selector's section took over from an older layout (its settings' `moved_from`, e.g.
    'baselines.gaussmi_lambda_L' -> 'gaussmi.lambda_L'), moved to where they live now, so configs
    written with earlier runs still load."""
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for section, settings in types.items():
        for old, new in getattr(settings, "moved_from", {}).items():
            table, key = old.split(".")
            if isinstance(data.get(table), dict) and key in data[table]:
                data.setdefault(section, {})[new] = data[table].pop(key)
                if not data[table]:
                    del data[table]
    return data


def _build_scenario(data: dict) -> ScenarioConfig:
    """The top level: the built-in sections, and every other table as the selector section of that name
    (each selector section at its defaults unless the data sets it)."""
    if not isinstance(data, dict):
        raise ConfigError(f"config: expected a table, got {data!r}")
    types = config_sections()
    data = _move_renamed_keys(data, types)
    builtin = {f.name for f in dataclasses.fields(ScenarioConfig)} - {"sections"}
    sections = {name: settings() for name, settings in types.items()}
    for name in sorted(set(data) - builtin):
        if name not in types:
            raise ConfigError(f"unknown config key '{name}' (valid: {', '.join(sorted(builtin | set(types)))}; "
                              "a selector's section is known once its selector is registered)")
        sections[name] = from_table(types[name], data.pop(name), f"{name}.")
    return dataclasses.replace(from_table(ScenarioConfig, data, ""), sections=sections)
