"""View-selection scoring on a recorded run's final map: 2D GauSS-MI exact and culled, and the
baselines' scoring, all on the same map and the same candidate library in the same run.

Restores the run's last checkpoint (map, reliability, planner, drone state), takes the whole
candidate library around the drone's final pose (every candidate, feasible or not: the worst
case of a step) and times, per scoring resolution: 2D GauSS-MI scored exactly (reliability.gain_floor
0) and with the configured floor (the cut first pass plus the exact re-scoring of the candidates
that can still win), whether both pick the same view, how many candidates were re-scored, and the
first pass's bound relative to the best MI, at each thread count of `--threads` (rows per count, so
the scaling shows), with the rasterizer's stage profile of the exact call (thread-ms summed over
cameras, and per candidate the culling spheres tested, splats projected and splats binned). Then
the baselines' own score() at the last thread count and their own
settings on the same poses (`--methods`), with their cost relative to ours (the paper reports
FisherRF at 22x, GauSS-MI at 5.3x and ActiveGS at 1.9x the time of 2D GauSS-MI).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from flightrecon.active import gaussmi2d
from flightrecon.active.protocol import MapView, Observation, scoring_intrinsics
from flightrecon.active.registry import make_selector
from flightrecon.active.selectors import GaussMI2D
from flightrecon.bench.active import library_poses
from flightrecon.bench.common import report, thread_counts, time_call
from flightrecon.errors import FlightReconError
from flightrecon.mapping.frames import expand_frame
from flightrecon.mission import Mission
from flightrecon.render import sided_feature_sums
from flightrecon.render.api import resolve_backend
from flightrecon.render.extension import load

NOT_IN_ALL = "needs --run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", help="run folder with a checkpoint (e.g. from `bench run` or `fly`)")
    p.add_argument("--sizes", default="", help="scoring resolutions WxH, comma separated (default: the run's "
                                               "scoring resolution and 640x480)")
    p.add_argument("--methods", default="gaussmi,fisherrf,activegs",
                   help="baselines whose own scoring is timed on the same poses (comma separated; '' for none)")
    p.add_argument("--threads", default="", help="thread counts to score at, comma separated (default: 1 and "
                                                 "the current count)")
    p.add_argument("--repeat", type=int, default=3)


def _sizes(spec: str, mission: Mission) -> list[tuple[int, int]]:
    if not spec:
        sel = mission.cfg.selector
        return [(sel.scoring_width, sel.scoring_height), (640, 480)]
    try:
        return [tuple(int(v) for v in part.lower().split("x")) for part in spec.split(",")]  # type: ignore[misc]
    except ValueError:
        raise FlightReconError(f"bench score: --sizes {spec!r}: give WxH pairs, e.g. 160x120,640x480") from None


def _profile(poses: np.ndarray) -> dict:
    """The rasterizer's stages in its last call: thread-ms summed over the cameras, work per candidate."""
    stats = load().last_stats()
    row = {f"{stage}_ms": 1e3 * stats[f"{stage}_s"] for stage in ("project", "bin", "sort", "blend")}
    row.update({f"{k}_per_cand": stats[k] / len(poses) for k in ("tests", "projected", "binned")})
    return row


def _ours(mission: Mission, poses: np.ndarray, width: int, height: int, repeat: int, threads: int) -> dict:
    cfg = mission.cfg
    mapper = mission.mapper
    splats = mapper.splats()
    rel = MapView(mapper, GaussMI2D.columns).column(GaussMI2D.COLUMN)
    T = torch.as_tensor(poses, dtype=torch.float32)
    K = scoring_intrinsics(cfg, width, height)
    floor = cfg.reliability.gain_floor
    common = dict(w_min=cfg.reliability.w_min, near=mapper.near, far=mapper.far, backend=cfg.mapper.backend)
    result: dict = {}

    def exact():
        result["exact"] = gaussmi2d.score_candidates(splats, rel, T, K, width, height, **common)

    def culled():
        result["culled"] = gaussmi2d.score_candidates(splats, rel, T, K, width, height, gain_floor=floor, **common)

    t_exact = time_call(exact, repeat=repeat)["median_s"]
    profile = _profile(poses) if resolve_backend(cfg.mapper.backend) == "cpu" else {}
    t_culled = time_call(culled, repeat=repeat)["median_s"]
    first = sided_feature_sums(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"],
                               torch.nn.functional.softplus(-rel), torch.linalg.inv(T),
                               K[None].expand(len(T), 3, 3).contiguous(), width, height, mapper.near, mapper.far,
                               w_min=cfg.reliability.w_min, floor=floor, backend=cfg.mapper.backend)
    best = float(result["exact"].max())
    contenders = len(gaussmi2d.can_still_win(first))
    return {"resolution": f"{width}x{height}", "threads": threads, "candidates": len(poses), "exact_ms": 1e3 * t_exact,
            "exact_ms_per_cand": 1e3 * t_exact / len(poses), "culled_ms": 1e3 * t_culled,
            "culled_ms_per_cand": 1e3 * t_culled / len(poses), "speedup": t_exact / t_culled,
            "same_argmax": bool(torch.argmax(result["exact"]) == torch.argmax(result["culled"])),
            "rescored": contenders, "gain_floor": floor,
            "max_bound_over_best": float(first.bound.max()) / best if best > 0 else float("nan"), **profile}


def _baseline(mission: Mission, method: str, poses: np.ndarray, repeat: int) -> dict:
    cfg = dataclasses.replace(mission.cfg, selector=dataclasses.replace(mission.cfg.selector, method=method))
    selector = make_selector(cfg)
    mapper = mission.mapper
    view = MapView(mapper, selector.columns)
    if method == "fisherrf":  # its training views: the frames the map was trained on
        for i, f in enumerate(mapper.frames):
            selector.observe(view, Observation(i, None, None, None, np.linalg.inv(f.viewmat.double().numpy())))
    if method.startswith("activegs"):  # its voxel map over the scene, from the frames the map was trained on
        selector.attach_scene(mission.rig.scene.bounds)
        for f in mapper.frames:
            selector.observe_space(expand_frame(f, torch.device("cpu"))[1][..., 0].numpy(), f.K.double().numpy(),
                                   f.T_wc)
    t = time_call(lambda: selector.score(view, poses), repeat=repeat)["median_s"]
    width = getattr(selector, "width", cfg.selector.scoring_width)
    height = getattr(selector, "height", cfg.selector.scoring_height)
    row = {"method": method, "resolution": f"{width}x{height}", "candidates": len(poses), "ms": 1e3 * t,
           "ms_per_cand": 1e3 * t / len(poses)}
    if method.startswith("activegs"):
        row["voxels_explored"] = int((~selector.voxels.unexplored).sum())
    return row


def run(args: argparse.Namespace) -> dict:
    if not args.run:
        raise FlightReconError("bench score: give --run RUN_DIR (a run folder with a checkpoint, e.g. from "
                               "`flightrecon bench run` or `flightrecon fly`)")
    run_dir = Path(args.run)
    mission = Mission.resume(run_dir, progress=False)
    if len(mission.mapper.map) == 0:
        raise FlightReconError(f"bench score: the run {run_dir} has an empty map (no checkpoint after a frame?)")
    poses = library_poses(mission)
    sizes = _sizes(args.sizes, mission)
    before = torch.get_num_threads()
    rows, baselines = [], []
    try:
        for threads in thread_counts(args.threads, "bench score --threads") or sorted({1, torch.get_num_threads()}):
            torch.set_num_threads(threads)  # the extension runs in torch's OpenMP runtime: this sets both
            rows += [_ours(mission, poses, w, h, args.repeat, threads) for w, h in sizes]
        ours_at_scoring = rows[-len(sizes)]["culled_ms"]  # the scoring resolution at the last count
        for method in [m.strip() for m in args.methods.split(",") if m.strip()]:
            row = _baseline(mission, method, poses, args.repeat)
            row["ratio_to_ours"] = row["ms"] / ours_at_scoring
            baselines.append(row)
    finally:
        torch.set_num_threads(before)
    extra = {"run": str(run_dir), "map": f"{len(mission.mapper.map)} splats after {mission.state.frame} frames",
             "baselines": baselines}
    return report("score", rows, getattr(args, "out", None), extra)
