"""Two flights at once against one alone: does a flight keep its speed when something else runs?

Each flight runs `flightrecon fly` in its own subprocess and run folder (no recording), first
alone, then two of the same flight concurrently, once per OpenMP wait policy, all in one call:
  short    the package's policy (flightrecon.threads): a short spin, then sleep;
  passive  OMP_WAIT_POLICY=passive: waiting threads sleep at once;
  spin     libgomp's own default when nothing is set (GOMP_SPINCOUNT=300000: spin, then sleep),
           i.e. what a flight did before the policy;
  active   OMP_WAIT_POLICY=active: waiting threads never sleep.
Per flight: wall time of the subprocess, median and max per-frame mapping time (t_map of the run
folder's frames.csv) and the ratios of the concurrent figures to the same policy's flight alone.
The rasterizer is built and the scene baked before the first flight, so no flight pays for them.
The alone rows also compare the policies on a quiet machine. A flight that outlives --timeout is
stopped and reported with the frames it finished.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from flightrecon import run_folder
from flightrecon.bench.common import report
from flightrecon.errors import FlightReconError
from flightrecon.threads import WAIT_VARIABLES

POLICIES = {"short": {"GOMP_SPINCOUNT": "10000"}, "passive": {"OMP_WAIT_POLICY": "passive"},
            "spin": {"GOMP_SPINCOUNT": "300000"},
            "active": {"OMP_WAIT_POLICY": "active"}}

NOT_IN_ALL = "several short flights, some of them concurrent, several minutes on 2 cores"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="default")
    p.add_argument("--frames", type=int, default=12, help="frame budget of each flight")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--policies", default="short,spin",
                   help=f"comma-separated wait policies to compare, of: {', '.join(POLICIES)}, or spin=N "
                        "(GOMP_SPINCOUNT=N)")
    p.add_argument("--threads", type=int, default=0, help="OMP_NUM_THREADS of each flight (0: libgomp's default)")
    p.add_argument("--timeout", type=float, default=600.0, help="s; a flight running longer is stopped")
    p.add_argument("--work-dir", default=None, help="run folders go here (default: a temporary folder, removed)")


def run(args: argparse.Namespace) -> dict:
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    unknown = [p for p in policies if _policy_env(p) is None]
    if unknown:
        raise FlightReconError(f"bench pair --policies: unknown {', '.join(unknown)} (choose from {', '.join(POLICIES)})")
    _warm_caches(args)
    work = Path(args.work_dir) if args.work_dir else Path(tempfile.mkdtemp(prefix="flightrecon-pair-"))
    rows = []
    try:
        for policy in policies:
            alone = _fly_together(args, policy, [work / policy / "alone"])[0]
            rows.append({"policy": policy, "mode": "alone", **alone})
            for k, flight in enumerate(_fly_together(args, policy, [work / policy / f"pair{k}" for k in range(2)])):
                rows.append({"policy": policy, "mode": f"pair {k}", **flight, **_ratios(flight, alone)})
    finally:
        if not args.work_dir:
            shutil.rmtree(work, ignore_errors=True)
    extra = {"flight": f"{args.scenario}, {args.frames} frames, {', '.join(args.overrides) or 'no overrides'}",
             "threads": args.threads or "libgomp default (cores in the affinity mask)",
             "goal": "each flight of a pair at most 2.5x its time alone (wall and per-frame mapping)"}
    return report("pair", rows, getattr(args, "out", None), extra)


def _warm_caches(args: argparse.Namespace) -> None:
    """Build the rasterizer and bake the scene now, so that no timed flight pays for them."""
    from flightrecon.render.extension import load
    from flightrecon.scenario import load_config
    from flightrecon.scene.source import scene_from_config
    from flightrecon.sim.world import bake_scene

    cfg = load_config(args.scenario, args.overrides)
    load()
    bake_scene(scene_from_config(cfg.scene), cfg.scene.cache_dir, cfg.scene.collision_voxel)


def _policy_env(policy: str) -> dict[str, str] | None:
    """The environment of a named policy or of spin=N; None if it is neither."""
    if policy in POLICIES:
        return POLICIES[policy]
    name, _, count = policy.partition("=")
    return {"GOMP_SPINCOUNT": count} if name == "spin" and count.isdigit() else None


def _fly_together(args: argparse.Namespace, policy: str, run_dirs: list[Path]) -> list[dict]:
    """Start one flight per run folder at once and wait for all; their figures, in order."""
    env = {k: v for k, v in os.environ.items() if k not in WAIT_VARIABLES}
    env.update(_policy_env(policy))
    if args.threads > 0:
        env["OMP_NUM_THREADS"] = str(args.threads)
    sets = [a for s in ["budget.frames=" + str(args.frames), *args.overrides] for a in ("--set", s)]
    procs = []
    for d in run_dirs:
        d.parent.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "flightrecon.cli", "fly", args.scenario, "--out", str(d), "--quiet",
               "--no-record", *sets]
        log = open(d.parent / f"{d.name}.log", "w")
        procs.append((subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT), log, time.perf_counter()))
    out = []
    for (proc, log, t0), d in zip(procs, run_dirs):
        try:
            rc = proc.wait(timeout=max(1.0, args.timeout - (time.perf_counter() - t0)))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            rc = "timeout"
        wall = time.perf_counter() - t0
        log.close()
        if rc not in (0, "timeout"):
            tail = (d.parent / f"{d.name}.log").read_text()[-2000:]
            raise FlightReconError(f"bench pair: the flight in {d} exited with {rc}:\n{tail}")
        out.append({"wall_s": wall, **_map_times(d), "finished": rc == 0})
    return out


def _map_times(run_dir: Path) -> dict:
    """Frames flown and the median and max mapping time per frame, from the run folder's frames.csv."""
    path = run_dir / run_folder.FRAMES
    rows = list(csv.DictReader(path.open())) if path.is_file() else []
    t_map = [float(r["t_map"]) for r in rows if r.get("t_map")]
    nan = float("nan")
    return {"frames": len(rows), "map_median_s": statistics.median(t_map) if t_map else nan,
            "map_max_s": max(t_map) if t_map else nan}


def _ratios(flight: dict, alone: dict) -> dict:
    return {f"{k}_ratio": flight[k] / alone[k] if alone[k] > 0 else float("nan")
            for k in ("wall_s", "map_median_s", "map_max_s")}
