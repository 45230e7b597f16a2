"""`flightrecon map DATASET --out DIR`: build a 2DGS map from a recorded RGB-D dataset, offline.

Trains online (frame by frame, as in flight) on the dataset's frames, holding out every k-th frame,
then renders every view and writes: map.ply, config.toml (the resolved config), metrics.json
(PSNR dB, SSIM, depth L1 cm per view and their means, for held-out and training views), and
renders/ with the held-out views' color and depth (16-bit mm PNG) beside the observed ones.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from flightrecon import fileio, run_folder
from flightrecon.config import to_toml
from flightrecon.dataset import encode_color_png, encode_depth_png, load_dataset
from flightrecon.errors import ConfigError
from flightrecon.metric_defs import mean_metrics, summary_line
from flightrecon.scenario import load_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("map", help="train a 2DGS map on a recorded dataset and evaluate held-out views")
    p.add_argument("dataset", help="dataset folder with transforms.json (e.g. a survey flight's)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--holdout", type=int, default=5, help="hold out every k-th frame for evaluation; 0: none")
    p.add_argument("--scenario", default=None, help="scenario TOML or name for the mapper/camera settings")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, e.g. mapper.k_new=30 (repeatable)")
    p.add_argument("--limit", type=int, default=None, help="use only the first N frames")
    p.add_argument("--export-3dgs", action="store_true", help="also write map_3dgs.ply with scale_2 for 3DGS viewers")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # torch and the rasterizer load only when mapping runs, not whenever the CLI starts
    from flightrecon.mapping.offline import evaluate_view, train_on_dataset
    from flightrecon.mapping.ply import save_map

    if args.holdout < 0:
        raise ConfigError(f"--holdout must be 0 or more, got {args.holdout}")
    cfg = load_config(args.scenario, args.overrides)
    ds = load_dataset(args.dataset)
    out = Path(args.out)
    fileio.write_text(out / run_folder.CONFIG, to_toml(cfg))
    t_start = time.perf_counter()

    def progress(k: int, total: int, stats, seconds: float) -> None:
        print(f"\rmapping frame {k + 1}/{total}: +{stats.added} splats, {stats.total} total, "
              f"{seconds:.2f} s", end="" if k + 1 < total else "\n", file=sys.stderr, flush=True)

    result = train_on_dataset(ds, cfg, args.holdout, args.limit, on_frame=progress)
    mapper = result.mapper
    save_map(mapper.map, out / run_folder.MAP)
    if args.export_3dgs:
        save_map(mapper.map, out / "map_3dgs.ply", for_3dgs=True)

    views: dict[str, list[dict]] = {"test": [], "train": []}
    for split, indices in (("test", result.test), ("train", result.train)):
        for i in indices:
            f = ds[i]
            m, color, depth = evaluate_view(mapper, f.rgb, f.depth, f.K, f.T_wc)
            views[split].append({"frame": f.name, **m})
            if split == "test":
                fileio.write_bytes(out / "renders" / f"{f.name}_color.png", encode_color_png(color))
                fileio.write_bytes(out / "renders" / f"{f.name}_depth.png", encode_depth_png(depth))
                fileio.write_bytes(out / "renders" / f"{f.name}_color_gt.png", encode_color_png(f.rgb))
    summary = {
        "dataset": str(Path(args.dataset).resolve()), "holdout": args.holdout,
        "frames_train": len(result.train), "frames_test": len(result.test), "splats": len(mapper.map),
        "map_mb": (out / run_folder.MAP).stat().st_size / 1e6,
        "seconds_per_frame_mean": float(np.mean(result.seconds)) if result.seconds else 0.0,
        "seconds_total": time.perf_counter() - t_start,
        "test": {"mean": mean_metrics(views["test"]), "per_view": views["test"]},
        "train": {"mean": mean_metrics(views["train"]), "per_view": views["train"]},
    }
    fileio.write_json(out / run_folder.METRICS, summary)
    for split in ("test", "train"):
        mm = summary[split]["mean"]
        if mm["views"]:
            print(f"{split} ({mm['views']} views): {summary_line(mm)}")
    print(f"{len(mapper.map)} splats, map.ply {summary['map_mb']:.2f} MB, "
          f"{summary['seconds_per_frame_mean']:.2f} s/frame; wrote {out}")
    return 0
