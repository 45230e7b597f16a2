"""Active loop: per-candidate scoring time over a flight, step breakdown, scoring vs a plain render.

Flies a short active run (default: the demo scenario), then, on the final map, times the
configured selector's own scoring of the candidate library per candidate (e.g.
`--set selector.method=fisherrf`), and 2D GauSS-MI scoring of the whole candidate library at the
scoring resolution and at 640x480, next to a plain one-channel render (unit features) of the same
map and cameras: the difference is what the information gain costs beyond rasterization. The
ranking of the library at the scoring resolution is compared with the ranking at 640x480
(Spearman's rho, same best view, full-resolution rank of the chosen view): the evidence for the
default scoring resolution. A full run's wall time is extrapolated from the mean per-frame time
and stated as such.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import numpy as np
import torch
from scipy.stats import spearmanr

from flightrecon.active import gaussmi2d
from flightrecon.active.protocol import MapView, scoring_intrinsics
from flightrecon.active.selectors import GaussMI2D
from flightrecon.bench.common import report, time_call
from flightrecon.control.trajectory import FlatState
from flightrecon.flight_profile import LOOP_STAGES
from flightrecon.mission import Mission
from flightrecon.render import render
from flightrecon.scenario import load_config



def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="demo")
    p.add_argument("--frames", type=int, default=10, help="frames of the benchmark flight")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--full-frames", type=int, default=200, help="frames of the full run to extrapolate to")
    p.add_argument("--repeat", type=int, default=3)


def library_poses(mission: Mission) -> np.ndarray:
    """Camera poses [C,4,4] of the candidate library around the drone's final state."""
    s = mission.flight.state
    start = FlatState(s.position, np.zeros(3), np.zeros(3), float(s.yaw), 0.0)
    return mission.candidate_poses(mission.planner.check(start, *mission.planner.library.poses(s.position, s.yaw)))


def _selector_time(mission: Mission, repeat: int) -> dict:
    """The configured selector's own score() of the final library, per candidate: its scoring
    resolution and all it recomputes per selection (e.g. FisherRF's H_train) included."""
    poses = library_poses(mission)
    t = time_call(lambda: mission.selector.score(mission.view, poses), repeat=repeat, warmup=0)["median_s"]
    return {"method": mission.cfg.selector.method, "candidates": len(poses), "ms_per_cand": 1e3 * t / len(poses)}


def _score_times(mission: Mission, width: int, height: int, repeat: int) -> dict:
    """Median seconds to score the library poses (MI) and to plain-render them, at width x height."""
    poses = torch.as_tensor(library_poses(mission), dtype=torch.float32)
    c = mission.cfg
    Ks = scoring_intrinsics(c, width, height)
    splats = mission.mapper.splats()
    rel = MapView(mission.mapper, GaussMI2D.columns).column(GaussMI2D.COLUMN)
    near, far = mission.mapper.near, mission.mapper.far

    last: list = []  # the scores of the last timed call, for the ranking comparison

    def score():
        last[:] = [gaussmi2d.score_candidates(splats, rel, poses, Ks, width, height, w_min=c.reliability.w_min,
                                              near=near, far=far)]

    ones = torch.ones(len(mission.mapper.map), 1)
    viewmats = torch.linalg.inv(poses)

    @torch.no_grad()
    def plain():
        for i in range(0, len(poses), 64):
            n = len(poses[i:i + 64])
            render(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"], ones,
                   viewmats[i:i + 64], Ks[None].expand(n, 3, 3).contiguous(), width, height, near=near, far=far,
                   outputs=("features",))

    t_score = time_call(score, repeat=repeat)["median_s"]
    t_plain = time_call(plain, repeat=repeat)["median_s"]
    return {"candidates": len(poses), "score_ms_per_cand": 1e3 * t_score / len(poses),
            "plain_render_ms_per_cand": 1e3 * t_plain / len(poses), "score_over_plain": t_score / t_plain,
            "scores": last[0].numpy()}


def ranking_agreement(coarse: np.ndarray, full: np.ndarray) -> dict:
    """How well scoring at a low resolution ranks candidates like full resolution does: Spearman's
    rho, whether both pick the same view, and the full-resolution rank of the low-resolution pick."""
    rank_of_pick = int((full > full[int(np.argmax(coarse))]).sum()) + 1
    return {"spearman": float(spearmanr(coarse, full).statistic), "same_best": bool(np.argmax(coarse) == np.argmax(full)),
            "full_res_rank_of_pick": rank_of_pick}


def run(args: argparse.Namespace) -> dict:
    cfg = load_config(args.scenario, [f"budget.frames={args.frames}", "output.record=false", *args.overrides])
    with tempfile.TemporaryDirectory() as tmp:
        mission = Mission(cfg, Path(tmp) / "run", progress=True)
        metrics = mission.run()
        rows = mission.state.records
        per_cand = [1e3 * r["t_score"] / r["n_feasible"] for r in rows
                    if r.get("n_feasible", 0) > 1 and "t_score" in r]
        trend = np.polyfit(np.arange(len(per_cand)), per_cand, 1)[0] if len(per_cand) > 1 else float("nan")
        frame_s = [sum(r.get(k, 0.0) for k in LOOP_STAGES) for r in rows]
        res = [(cfg.selector.scoring_width, cfg.selector.scoring_height), (640, 480)]
        scoring = [{"resolution": f"{w}x{h}", **_score_times(mission, w, h, args.repeat)} for w, h in res]
        selector = _selector_time(mission, args.repeat)
    agreement = ranking_agreement(scoring[0].pop("scores"), scoring[1].pop("scores"))
    breakdown = {k: statistics.median(r[k] for r in rows if k in r) for k in LOOP_STAGES if any(k in r for r in rows)}
    extra = {
        "flight": f"{args.scenario} {cfg.camera.width}x{cfg.camera.height}, {len(rows)} frames, "
                  f"{metrics['splats']} splats at the end",
        "selector_score_on_final_map": selector,
        "in_loop_score_ms_per_candidate_mean": float(np.mean(per_cand)) if per_cand else float("nan"),
        "in_loop_score_ms_per_candidate_by_frame": [round(x, 3) for x in per_cand],
        "trend_ms_per_candidate_per_frame": float(trend),
        "step_breakdown_median_s": {k: round(v, 4) for k, v in breakdown.items()},
        "ranking_vs_640x480": agreement,
        "mean_frame_s": float(np.mean(frame_s)),
        "extrapolated_full_run_min": float(np.mean(frame_s)) * args.full_frames / 60.0,
    }
    return report("active", scoring, args.out, extra)
