#!/usr/bin/env python3
"""Say whether two run folders hold the same flight: map.ply byte for byte, and frames.csv,
trajectory.csv, diagnosis.csv and metrics.json with the wall-clock and thread-count columns left out.

For refactors that must not change behaviour: fly the same seeded scenario before and after, then
`python tools/compare_runs.py RUN_BEFORE RUN_AFTER` (exit status 1 on a difference)."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

TIMING = ("t_", "wall_time", "mean_times", "threads")  # threads: sized to the machine's load (threads.FreeCores)


def _timeless(name: str) -> bool:
    return not name.startswith(TIMING)


def _csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if _timeless(k)} for row in csv.DictReader(f)]


def _json(path: Path) -> dict:
    return {k: v for k, v in json.loads(path.read_text()).items() if _timeless(k)}


def compare(a: Path, b: Path) -> list[str]:
    """The differences between two run folders, one line each (empty: the same flight)."""
    diffs = []
    for name, read in (("map.ply", Path.read_bytes), ("frames.csv", _csv), ("trajectory.csv", _csv),
                       ("diagnosis.csv", _csv), ("metrics.json", _json)):
        pa, pb = a / name, b / name
        if not pa.exists() and not pb.exists():
            continue
        if pa.exists() != pb.exists():
            diffs.append(f"{name}: only in {a if pa.exists() else b}")
        elif read(pa) != read(pb):
            diffs.append(f"{name}: differs")
    return diffs


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    diffs = compare(Path(sys.argv[1]), Path(sys.argv[2]))
    print("\n".join(diffs) if diffs else "same flight")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
