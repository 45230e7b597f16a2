"""`flightrecon selectors`: the view selectors `selector.method` can name, built-in and from plug-ins.

For each: its role (what `sweep` flies by default and what the report pairs against), the config
section it declares with its keys and defaults, and the map columns it keeps. Plug-ins that could
not be loaded are listed with why, so a broken install is visible before a sweep is started.
"""

from __future__ import annotations

import argparse
import dataclasses


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("selectors", help="list the view selectors (built-in and plug-ins) with their settings")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flightrecon.active.registry import plugin_errors, selectors

    for name, cls in selectors().items():
        origin = "" if cls.__module__.startswith("flightrecon.") else f"  (plug-in: {cls.__module__})"
        print(f"{name}  [{cls.role}]{origin}")
        doc = (cls.__doc__ or "").strip().splitlines()
        if doc:
            print(f"    {doc[0]}")
        if cls.section is not None:
            keys = ", ".join(f"{f.name}={f.default if f.default is not dataclasses.MISSING else f.default_factory()}"
                             for f in dataclasses.fields(cls.settings))
            print(f"    section [{cls.section}]: {keys}")
        if cls.columns:
            print(f"    map columns: {', '.join(f'{k} {tuple(v)}' for k, v in cls.columns.items())}")
    for ep, why in plugin_errors().items():
        print(f"{ep}  [left out]  {why}")
    return 0
