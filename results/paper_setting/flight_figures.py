"""Print one finished paper-setting flight's figures for README.md's tables (results, pace, provenance):
`python flight_figures.py SCENE METHOD...`."""

import csv
import json
import statistics
import sys
from pathlib import Path

BASE = Path(__file__).resolve().parent / "runs" / "office0"
scene = sys.argv[1]
for m in sys.argv[2:]:
    d = BASE / scene / m / "seed0"
    ev = json.loads((d / "eval.json").read_text())
    me = json.loads((d / "metrics.json").read_text())
    rows = list(csv.DictReader(open(d / "frames.csv")))
    tm = [float(r["t_map"]) for r in rows]
    th = [int(r["threads"]) for r in rows]
    blocks = [round(statistics.mean(tm[i:i + 50]), 1) for i in range(0, len(tm), 50)]
    print(f"{scene} {m}: psnr {ev['psnr']:.2f} cov {ev['psnr_covered']:.2f} depthL1 {ev['depth_l1_cm']:.2f} "
          f"F {ev['fscore']:.3f} ssim {ev['ssim']:.3f} lpips {ev['lpips']:.3f} flown {me['flight_distance_m']:.1f} "
          f"wall {me['wall_time_s']:.0f}s ({me['wall_time_s'] / 60:.1f} min) median t_map {statistics.median(tm):.1f} "
          f"means by 50 {blocks} splats {me['splats']} threads {sorted(set(th))} "
          f"(2 in {sum(t == 2 for t in th)} frames) contacts {me['contacts']} recoveries {me['recoveries']}")
    with open(d / "eval_over_frames.csv", newline="") as f:
        print("   PSNR over frames:", [(r["frame"], round(float(r["psnr"]), 2)) for r in csv.DictReader(f)])
    print("   provenance:", [(s["commit"][:10], s["dirty"], s["cpu"]["model"])
                             for s in json.loads((d / "provenance.json").read_text())["segments"]])
