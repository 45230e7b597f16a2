#!/usr/bin/env python3
"""How far the views a flight chose could take its map with a larger mapping budget.

Restores each run's last checkpoint (the map, its optimizer state and the stored frames), refines
the map with replay-only iterations over the flight's own frames (`OnlineMapper.refine`) and scores
the evaluation views after each round, as the loop's in-flight evaluation does. The flight spent
frames x (K_new + K_replay) iterations; `--budgets 1 3` adds 1x, then 3x that in all. A gap between
methods that stays as the map converges is a gap in the views they chose; one that closes was a
gap in the mapping budget. Rows are appended to `--out` as they are measured, and a rerun skips
the (run, budget) pairs already there, so a long call can be resumed.

    python tools/mapping_ceiling.py RUN [RUN ...] --budgets 1 3 --out ceiling.csv
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

from flightrecon.mission import Mission

COLUMNS = ["run", "scene", "method", "seed", "extra_budget", "extra_iterations", "psnr", "psnr_covered",
           "depth_l1_cm", "refine_s"]


def _done(out: Path) -> set[tuple[str, str]]:
    if not out.is_file():
        return set()
    with open(out, newline="") as f:
        return {(r["run"], r["extra_budget"]) for r in csv.DictReader(f)}


def _append(out: Path, row: dict) -> None:
    new = not out.is_file()
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        if new:
            w.writeheader()
        w.writerow(row)


def ceiling(run_dir: Path, budgets: list[float], out: Path) -> None:
    """Score the run's final map, then after each cumulative extra budget; append a row per budget."""
    done = _done(out)
    todo = [0.0] + sorted(budgets)
    if all((str(run_dir), f"{b:g}") in done for b in todo):
        return
    mission = Mission.resume(run_dir, progress=False)
    cfg, mapper = mission.cfg, mission.mapper
    flight_iters = len(mapper.frames) * (cfg.mapper.k_new + cfg.mapper.k_replay)
    spent, seconds = 0, 0.0
    for b in todo:
        t0 = time.perf_counter()
        mapper.refine(round(b * flight_iters) - spent)
        seconds += time.perf_counter() - t0
        spent = round(b * flight_iters)
        if (str(run_dir), f"{b:g}") in done:
            continue
        q = mission.evaluation.evaluate(mapper)
        row = {"run": str(run_dir), "scene": cfg.scene.name, "method": cfg.selector.method, "seed": cfg.seed,
               "extra_budget": f"{b:g}", "extra_iterations": spent, "psnr": f"{q['psnr']:.4f}",
               "psnr_covered": f"{q['psnr_covered']:.4f}", "depth_l1_cm": f"{q['depth_l1_cm']:.4f}",
               "refine_s": f"{seconds:.1f}"}
        _append(out, row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="run folders with a checkpoint")
    p.add_argument("--budgets", nargs="+", type=float, default=[1.0, 3.0],
                   help="cumulative extra iterations, in multiples of the flight's own (default 1 3)")
    p.add_argument("--out", type=Path, required=True, help="CSV the rows are appended to")
    args = p.parse_args()
    if any(not b > 0 for b in args.budgets):
        p.error("--budgets must be positive multiples")
    for run in args.runs:
        ceiling(run, args.budgets, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
