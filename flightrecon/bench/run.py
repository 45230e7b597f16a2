"""A whole flight, measured: wall time, the per-stage split, scoring per candidate, map size and
quality, for one scenario at its own budget (default: the CPU default, 200 frames).

Flies the scenario into a run folder (kept: `bench score --run` times scoring on its final map;
a killed bench resumes with the same command, and the wall time then sums the segments' step
times, as `metrics.json` does). Reports the run's wall time (the loop's steps plus the final
evaluation), each stage's total and median per frame, the in-loop scoring time per feasible
candidate (median over the flight), splats and map.ply size, the evaluation metrics, and the
mapping profile of `bench map` (flightrecon.profiling) over the frames this call flew.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from flightrecon import profiling, run_folder
from flightrecon.bench.common import report
from flightrecon.flight_profile import LOOP_STAGES
from flightrecon.mission import Mission
from flightrecon.scenario import load_config


NOT_IN_ALL = "a whole 200-frame flight, about half an hour on 2 cores"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="default")
    p.add_argument("--frames", type=int, default=None, help="frame budget (default: the scenario's)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--run-dir", default=None, help="run folder (default: runs/bench/<scenario>)")


def run(args: argparse.Namespace) -> dict:
    overrides = ["output.record=false", *args.overrides]
    if args.frames is not None:
        overrides.append(f"budget.frames={args.frames}")
    cfg = load_config(args.scenario, overrides)
    run_dir = Path(args.run_dir or Path(cfg.output.run_root) / "bench" / Path(args.scenario).stem)
    t0 = time.perf_counter()
    if (run_dir / run_folder.CHECKPOINT).is_file() and not (run_dir / run_folder.METRICS).is_file():
        mission = Mission.resume(run_dir)
    else:
        mission = Mission(cfg, run_dir)
    with profiling.profiling() as prof:
        metrics = mission.run()
    wall = time.perf_counter() - t0
    rows = mission.state.records
    stages = []
    for k in LOOP_STAGES:
        vals = [r[k] for r in rows if k in r]
        if vals:
            stages.append({"stage": k.removeprefix("t_"), "total_s": sum(vals), "median_s": statistics.median(vals),
                           "share": sum(vals) / max(metrics["wall_time_s"], 1e-9)})
    per_cand = [1e3 * r["t_score"] / r["n_feasible"] for r in rows if r.get("n_feasible", 0) > 1 and "t_score" in r]
    ev = metrics["eval"]
    extra = {
        "run": str(run_dir),
        "flight": f"{cfg.name} {cfg.scene.name} {cfg.camera.width}x{cfg.camera.height}, K {cfg.mapper.k_new}/"
                  f"{cfg.mapper.k_replay}, {metrics['frames']} frames, method {cfg.selector.method}",
        "wall_time_min": metrics["wall_time_s"] / 60.0,
        "this_call_min": wall / 60.0,
        "map_s_per_frame_median": statistics.median(r["t_map"] for r in rows),
        "score_ms_per_candidate_median": statistics.median(per_cand) if per_cand else float("nan"),
        "splats": metrics["splats"], "map_mb": metrics["map_mb"],
        "eval_psnr": ev.get("psnr"), "eval_depth_l1_cm": ev.get("depth_l1_cm"),
        "flight_distance_m": metrics["flight_distance_m"],
    }
    # the mapping profile of the frames this call flew (a resumed run: of its remaining frames)
    extra["map_profile"] = profiling.breakdown(prof, max(1, prof.calls["add_frame"]))
    return report("run", stages, getattr(args, "out", None), extra)
