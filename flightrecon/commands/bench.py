"""`flightrecon bench NAME`: run one benchmark module of flightrecon.bench, or all of them."""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from flightrecon import bench


def _bench_names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(bench.__path__) if m.name != "common")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure speed (world, flight, render, plan, map, active, all)")
    bsub = p.add_subparsers(dest="bench_name", metavar="NAME")
    for name in _bench_names():
        mod = importlib.import_module(f"{bench.__name__}.{name}")
        bp = bsub.add_parser(name, help=(mod.__doc__ or "").strip().splitlines()[0])
        bp.add_argument("--out", default=None, help="also write the results as JSON here")
        mod.add_arguments(bp)
        bp.set_defaults(func=lambda a, m=mod: _run(m, a))
    ap = bsub.add_parser("all", help="every benchmark with its defaults")
    ap.set_defaults(func=_run_all)
    p.set_defaults(func=lambda a: p.print_help())


def _run(mod, args) -> int:
    mod.run(args)
    return 0


def _run_all(args) -> int:
    for name in _bench_names():
        mod = importlib.import_module(f"{bench.__name__}.{name}")
        parser = argparse.ArgumentParser()
        parser.add_argument("--out", default=None)
        mod.add_arguments(parser)
        mod.run(parser.parse_args([]))
    return 0


