"""The quality checks (plan.md, plan_paper.md): after minus before per scene, with the scene as the unit.

Reads each arm's runs under <root>/<arm>/<scenario>/<scene>/gaussmi2d/seed0 (eval.json, metrics.json,
frames.csv; by default the CPU-default check's runs/<arm>/default, with --paper the paper-setting
check's runs_paper/<arm>/office0) and prints, per scene and as mean and 95% t-interval over the scenes both arms have
finished: PSNR, depth L1, splats, map size and the flight's median mapping seconds per frame (the
last only as flown: the arms shared the cores, so it is no speed measurement).

    python results/speed/issue56/compare.py [--paper]
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
from pathlib import Path

from scipy import stats

HERE = Path(__file__).resolve().parent
ARMS = ("before", "after")
MEASURES = (("PSNR dB", "eval", "psnr"), ("depth L1 cm", "eval", "depth_l1_cm"),
            ("F-score", "eval", "fscore"), ("splats", "metrics", "splats"), ("map MB", "metrics", "map_mb"),
            ("flown m", "metrics", "flight_distance_m"))


def run_figures(run: Path) -> dict[str, float]:
    files = {"eval": json.loads((run / "eval.json").read_text()),
             "metrics": json.loads((run / "metrics.json").read_text())}
    out = {label: float(files[source][key]) for label, source, key in MEASURES}
    with open(run / "frames.csv", newline="") as fh:
        out["map s/frame (shared cores)"] = statistics.median(float(r["t_map"]) for r in csv.DictReader(fh))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", action="store_true", help="the paper-setting check (plan_paper.md)")
    args = parser.parse_args()
    root, scenario = ("runs_paper", "office0") if args.paper else ("runs", "default")
    runs = {arm: {p.parents[2].name: p.parents[0] for p in (HERE / root / arm).glob(f"{scenario}/*/gaussmi2d/seed0/eval.json")}
            for arm in ARMS}
    scenes = sorted(set(runs["before"]) & set(runs["after"]))
    figures = {arm: {s: run_figures(runs[arm][s]) for s in scenes} for arm in ARMS}
    labels = list(figures["before"][scenes[0]]) if scenes else []
    print("| measure | " + " | ".join(f"{s} before / after" for s in scenes) + " | mean after - before | 95% t |")
    print("|---" * (len(scenes) + 3) + "|")
    for label in labels:
        diffs = [figures["after"][s][label] - figures["before"][s][label] for s in scenes]
        mean = statistics.fmean(diffs)
        half = (stats.t.ppf(0.975, len(diffs) - 1) * statistics.stdev(diffs) / len(diffs) ** 0.5
                if len(diffs) > 1 else float("nan"))
        cells = [f"{figures['before'][s][label]:.4g} / {figures['after'][s][label]:.4g}" for s in scenes]
        print(f"| {label} | " + " | ".join(cells) + f" | {mean:+.4g} | ±{half:.3g} |")


if __name__ == "__main__":
    main()
