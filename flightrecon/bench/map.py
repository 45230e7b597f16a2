"""Online 2DGS mapping: seconds per frame (K_new + K_replay), model size, and held-out quality.

Trains on a recorded dataset (a survey flight: `flightrecon fly office0 --survey`) exactly as
`flightrecon map` does. Per dataset it reports the distribution of the wall time of one `add_frame`
(median, mean, p90, max: a few slow frames can dominate the mean),
the map.ply size scaled to 100 training frames, and (with --quality) PSNR / SSIM / depth L1 on the
held-out views (every `--holdout`-th frame) and on the training views, plus the held-out views' share
of pixels seen by a training view (`test_coverage`) and PSNR / depth L1 on those pixels alone.

The profile splits the mapping time into its stages (flightrecon.profiling: splat axes, projection,
binning, forward and backward blend, loss terms, SSIM, depth normals, optimizer step, view setup,
densify, prune), each as ms per iteration or per frame and as a share of all mapping time, and puts
the forward blend's throughput next to this CPU's ceiling, probed in the same run
(`blend_ceiling`). `--scaling 1,2` then times iterations on the trained map at each thread count.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from flightrecon import profiling
from flightrecon.dataset import load_dataset
from flightrecon.fileio import write_json
from flightrecon.mapping.offline import evaluate_view, masked_metrics, train_on_dataset, training_coverage
from flightrecon.mapping.ply import save_map
from flightrecon.metric_defs import mean_metrics
from flightrecon.render.extension import load
from flightrecon.scenario import load_config

from flightrecon.bench.common import report, thread_counts


NOT_IN_ALL = "needs --dataset"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", action="append", default=[],
                   help="dataset folder (repeatable, e.g. a 320x240 and a 640x480 survey)")
    p.add_argument("--frames", type=int, default=None, help="use only the first N frames of each dataset")
    p.add_argument("--holdout", type=int, default=5)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--scaling", default="1,2",
                   help="thread counts at which iterations on the trained map are timed ('' for none)")
    p.add_argument("--scaling-iterations", type=int, default=20)
    p.add_argument("--quality", action="store_true", help="also render and score every view after training")
    p.add_argument("--scenario", default=None,
                   help="take the mapper settings of this scenario (e.g. default, the CPU default); "
                        "default: the config defaults (the paper's)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, e.g. mapper.backend=reference")


def run(args: argparse.Namespace) -> dict:
    if not args.dataset:
        raise SystemExit("bench map: give --dataset DIR (record one with `flightrecon fly office0 --survey`)")
    torch.set_num_threads(args.threads)
    cfg = load_config(args.scenario, args.overrides)
    scaling = thread_counts(args.scaling, "bench map --scaling")  # a bad value fails before training
    ceiling = load().blend_ceiling(1.0)
    rows, profiles = [], {}
    for path in args.dataset:
        ds = load_dataset(path)
        with profiling.profiling() as prof:
            res = train_on_dataset(ds, cfg, args.holdout, args.frames)
        name = Path(path).name
        profiles[name] = {"stages": profiling.breakdown(prof, len(res.train)),
                          "blend": profiling.blend_rates(prof, ceiling, args.threads)}
        with tempfile.TemporaryDirectory() as tmp:
            size = save_map(res.mapper.map, Path(tmp) / "map.ply").stat().st_size
        row = {"dataset": name, "size": f"{ds.width}x{ds.height}", "frames": len(res.train),
               "k_new": cfg.mapper.k_new, "k_replay": cfg.mapper.k_replay, "threads": args.threads,
               "backend": cfg.mapper.backend, "s_per_frame_median": statistics.median(res.seconds),
               "s_per_frame_mean": float(np.mean(res.seconds)),
               "s_per_frame_p90": float(np.percentile(res.seconds, 90)),
               "s_per_frame_max": max(res.seconds), "splats": len(res.mapper.map),
               "mb_per_100_frames": size / 1e6 * 100.0 / max(1, len(res.train))}
        if args.quality:
            training = [ds[i] for i in res.train]
            for split, idx in (("test", res.test), ("train", res.train)):
                views = []
                for i in idx:
                    f = ds[i]
                    m, color, depth = evaluate_view(res.mapper, f.rgb, f.depth, f.K, f.T_wc)
                    if split == "test":  # scores where some training view saw the surface
                        covered = training_coverage(f, training)
                        m["coverage"] = float(covered.sum() / max(1, (f.depth > 0).sum()))
                        m.update({f"{k}_covered": v for k, v in
                                  masked_metrics(color, depth, f.rgb, f.depth, covered).items()})
                    views.append(m)
                row.update({f"{split}_{k}": v for k, v in mean_metrics(views).items()})
        row.update({f"ms_per_replay_iteration_{n}_threads": ms for n, ms in
                    _scaling(res, scaling, args.scaling_iterations).items()})
        torch.set_num_threads(args.threads)
        rows.append(row)
    result = report("map", rows, None, extra={"note": "wall times on a shared machine; see machine.cores",
                                               "ceiling": ceiling})
    for name, prof in profiles.items():
        print(f"\n{name}:")
        report("map-profile", prof["stages"], None, extra={"blend": prof["blend"]})
    result["profiles"] = profiles
    if args.out:
        write_json(args.out, result)
    return result


def _scaling(res, counts: list[int], iterations: int) -> dict[int, float]:
    """Median ms of one replay iteration (`refine(1)`: a stored frame, its view setup, one step) on the
    trained map, per thread count. The replay draws are the mapper's own, so every count sees
    different frames: the medians compare, single samples do not."""
    out = {}
    for n in counts if res.mapper.frames else []:
        torch.set_num_threads(n)
        res.mapper.refine(2)  # warm up at this thread count
        samples = []
        for _ in range(iterations):
            t0 = time.perf_counter()
            res.mapper.refine(1)
            samples.append(time.perf_counter() - t0)
        out[n] = 1e3 * statistics.median(samples)
    return out
