"""`flightrecon sweep`: the paper's experiments as one command (flights, evaluation, tables, figures).

Runs every (scene, method, seed) of a scenario into <run_root>/<scenario>/<scene>/<method>/seed<k>/
(finished runs are skipped, killed ones resumed from their checkpoint), evaluates each (rendering
and mesh metrics, flightrecon.experiments.run_eval), then writes the tables and figures to
<run_root>/<scenario>/report/ (or --report). All methods share our mapper, planner and candidate
library, so the comparison isolates the selection criterion.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from flightrecon.scene.procedural import SCENE_NAMES


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="run scenes x methods x seeds, evaluate, write the paper's tables and figures")
    p.add_argument("--scenario", default="default", help="scenario TOML path or name in scenarios/ (default: default)")
    p.add_argument("--scenes", nargs="+", default=list(SCENE_NAMES), help="scene names (default: the eight)")
    p.add_argument("--methods", nargs="+", default=None,
                   help="selector names (selector.method values; default: every registered method, baseline "
                        "and floor, without the ablations: `flightrecon selectors` lists them)")
    p.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per scene and method (default 3)")
    p.add_argument("--scene-seeds", type=int, nargs="+", default=None, metavar="K",
                   help="fly each scene's variants scene.seed = K... (each a scene of its own in the report, "
                        "folder <scene>.v<K>); default: the scenario's scene.seed")
    p.add_argument("--jobs", type=int, default=1, help="runs in parallel (default 1)")
    p.add_argument("--max-runs", type=int, default=None,
                   help="bring at most this many unfinished runs to an end, then report what is finished "
                        "(a part of a sweep; run again to continue; 0: fly nothing, only rewrite the report)")
    p.add_argument("--retry-failed", action="store_true",
                   help="fly runs whose flight failed earlier on from their checkpoint (after fixing the cause)")
    p.add_argument("--allow-code-change", action="store_true",
                   help="resume killed runs even when their earlier frames ran other code (recorded in each "
                        "run's provenance.json; the report then marks the tables as mixed)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local process pool, or a Ray cluster (--ray-address; default a local instance)")
    p.add_argument("--ray-address", default=None, help="address of a running Ray cluster")
    p.add_argument("--ray-transfer", choices=("auto", "always", "never"), default="auto",
                   help="copy each finished run's result files (not its maps or checkpoints) back to the run "
                        "root: auto from nodes that cannot see it (no shared file system), always, or never")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value for every run (repeatable)")
    p.add_argument("--run-root", default=None, help="root folder of the runs (default: output.run_root)")
    p.add_argument("--report", default=None, help="where tables and figures go (default: <root>/<scenario>/report)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flightrecon.errors import FlightReconError
    from flightrecon.experiments.report import collect, write_figures, write_tables
    from flightrecon.experiments.sweep import execute, plan_runs
    from flightrecon.experiments.sweep_run import failure

    if args.seeds < 1 or args.jobs < 1 or (args.max_runs is not None and args.max_runs < 0):
        raise FlightReconError("sweep: --seeds and --jobs must be at least 1, and --max-runs at least 0")
    if args.methods is None:
        from flightrecon.active.registry import methods_with_role

        args.methods = methods_with_role("method", "baseline", "floor")
    specs = plan_runs(args.scenario, args.scenes, args.methods, args.seeds, args.overrides, args.run_root,
                      args.scene_seeds)
    execute(specs, args.jobs, args.executor, args.ray_address, log=lambda s: print(s, flush=True),
            max_runs=args.max_runs, retry_failed=args.retry_failed, allow_code_change=args.allow_code_change,
            transfer=args.ray_transfer)
    report = Path(args.report) if args.report else specs[0].run_dir.parents[2] / "report"
    recs = collect([s.run_dir for s in specs])
    failed = {str(s.run_dir): why for s in specs if (why := failure(s)) is not None}
    files = write_tables(recs, report, failed) + write_figures(recs, report)
    print((report / "overall.md").read_text())
    print((report / "efficiency.md").read_text())
    print((report / "summary.md").read_text())
    print(f"{len(files)} files in {report}")
    return 0
