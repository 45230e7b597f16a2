"""`flightrecon bench NAME [options]`: run one benchmark module of flightrecon.bench, or all of them.

Benchmark modules import the heavy parts they measure, so they are imported only when run, never
when the CLI starts; `flightrecon bench NAME --help` shows a benchmark's own options.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from flightrecon import bench
from flightrecon.errors import FlightReconError


def _bench_names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(bench.__path__) if m.name != "common")


def register(sub: argparse._SubParsersAction) -> None:
    names = _bench_names()
    p = sub.add_parser("bench", help=f"measure speed ({', '.join(names)}, all)",
                       description=f"benchmarks: {', '.join(names)}, or all (each with its defaults)")
    p.add_argument("name", metavar="NAME", help=f"one of: {', '.join(names)}, all")
    p.add_argument("options", nargs=argparse.REMAINDER, help="the benchmark's own options (NAME --help)")
    p.set_defaults(func=_run)


def _parser(name: str):
    mod = importlib.import_module(f"{bench.__name__}.{name}")
    parser = argparse.ArgumentParser(prog=f"flightrecon bench {name}", description=mod.__doc__)
    parser.add_argument("--out", default=None, help="also write the results as JSON here")
    mod.add_arguments(parser)
    return mod, parser


def _run(args: argparse.Namespace) -> int:
    names = _bench_names()
    if args.name == "all":
        for name in names:
            mod, parser = _parser(name)
            if getattr(mod, "NOT_IN_ALL", None):  # needs an input, or is a whole flight
                print(f"bench {name}: skipped by `bench all` ({mod.NOT_IN_ALL}); run `flightrecon bench {name}`")
                continue
            mod.run(parser.parse_args([]))
        return 0
    if args.name not in names:
        raise FlightReconError(f"unknown benchmark '{args.name}' (choose from {', '.join(names)}, all)")
    mod, parser = _parser(args.name)
    mod.run(parser.parse_args(args.options))
    return 0
