"""`flightrecon profile RUN`: where a flight's time went, stage by stage, over blocks of frames.

Reads the run's profile.csv (every flight writes it; flightrecon.flight_profile) and prints each
stage's seconds per frame and its share of the loop's time, over the whole flight and per block of
`--every` frames, so a growing map's cost shows where it grows.
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("profile", help="where a flight's time went: each stage's share, per block of frames")
    p.add_argument("run_dir", help="run folder (with profile.csv)")
    p.add_argument("--every", type=int, default=50, help="frames per block (default 50)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flightrecon.bench.common import markdown_table
    from flightrecon.flight_profile import read_profile, summary

    rows = read_profile(args.run_dir)
    print(f"{args.run_dir}: {len(rows)} frames; seconds per frame and share of the loop's time\n")
    print(markdown_table(summary(rows, args.every)))
    return 0
