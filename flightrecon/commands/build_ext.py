"""`flightrecon build-ext`: compile the C++ rasterizer now (set-up step) instead of on first use."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-ext", help="compile the C++ 2DGS rasterizer (cached by source hash)")
    p.add_argument("--verbose", action="store_true", help="show the compiler's output")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from flightrecon.render.extension import cache_dir, load, source_hash

    ext = load(verbose=args.verbose)
    print(f"C++ rasterizer ready ({ext.num_threads()} threads): {cache_dir() / source_hash()}")
    return 0
