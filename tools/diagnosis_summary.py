#!/usr/bin/env python3
"""Summarize the diagnosed runs under a folder (runs flown with `output.diagnose`): per scene and
method, the share of the visible surface seen at frames 20 and 40 and at the end, the moves
chosen (stay, turn, step), and for 2D GauSS-MI and its variants the chosen views' MI split by
kind of splat and its share on occlusion-edge pixels.

`python tools/diagnosis_summary.py RUN_ROOT [--markdown]`; RUN_ROOT holds .../<scene>/<method>/seed<k>/.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from flightrecon.active.diagnosis import KINDS


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def summarize(run: Path) -> dict:
    """One diagnosed run folder's summary (see the module docstring)."""
    diag = _rows(run / "diagnosis.csv")
    seen = [float(r["surface_seen"]) for r in diag]
    moves = [r.get("move", "") for r in diag]
    out = {"scene": run.parent.parent.name, "method": run.parent.name, "seed": run.name,
           "seen_20": seen[min(20, len(seen) - 1)], "seen_40": seen[min(40, len(seen) - 1)], "seen_end": seen[-1],
           "stay": moves.count("stay"), "turn": moves.count("turn"), "step": moves.count("step")}
    scored = [r for r in diag if r.get("mi")]
    total = sum(float(r["mi"]) for r in scored)
    if total > 0:
        for k in KINDS:
            out[f"mi_{k}"] = sum(float(r[f"mi_{k}"]) for r in scored) / total
        out["mi_on_edges"] = sum(float(r["mi_edge_share"]) * float(r["mi"]) for r in scored
                                 if r["mi_edge_share"] not in ("", "nan")) / total
        out["edge_pixels"] = sum(float(r["edge_pixel_share"]) for r in scored) / len(scored)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path)
    args = ap.parse_args()
    runs = sorted(p.parent for p in args.root.glob("**/seed*/diagnosis.csv"))
    cols = ["scene", "method", "seed", "seen_20", "seen_40", "seen_end", "stay", "turn", "step", "mi_negative",
            "mi_weak", "mi_back_seen", "mi_back_unseen", "mi_on_edges", "edge_pixels"]
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for run in runs:
        s = summarize(run)
        cells = []
        for c in cols:
            v = s.get(c, "")
            cells.append(f"{v:.3f}" if isinstance(v, float) and not math.isnan(v) else str(v))
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
