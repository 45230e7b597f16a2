"""`flightrecon fly SCENARIO --survey`: fly the drone in the scenario's scene and write what it saw.

The survey mode flies the scripted loop of flightrecon.survey and writes an RGB-D dataset. The
active loop (view selection with 2D GauSS-MI) will be the default mode; until it exists a plain
`fly` says so.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from flightrecon.config import ScenarioConfig, load_config
from flightrecon.errors import FlightReconError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fly", help="fly a scenario (--survey: scripted loop that writes an RGB-D dataset)")
    p.add_argument("scenario", help="scenario TOML path or name in scenarios/")
    p.add_argument("--survey", action="store_true", help="fly the scripted survey loop and write a dataset")
    p.add_argument("--out", default=None, help="output folder (default: <output.run_root>/<scenario>/<mode>/seed<k>)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set camera.width=320 (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def default_out_dir(cfg: ScenarioConfig, mode: str) -> Path:
    return Path(cfg.output.run_root) / cfg.name / mode / f"seed{cfg.seed}"


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.scenario, args.overrides)
    progress = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    if args.survey:
        return _run_survey(cfg, Path(args.out) if args.out else default_out_dir(cfg, "survey"), progress)
    raise FlightReconError("the active flight loop is not available yet; use `flightrecon fly SCENARIO --survey`")


def _run_survey(cfg: ScenarioConfig, out: Path, progress) -> int:
    from flightrecon.survey import run_survey

    t0 = time.perf_counter()
    r = run_survey(cfg, out, progress)
    progress(f"wrote {r.frames} frames to {r.dataset} ({r.flight_time:.1f} s of flight in "
             f"{time.perf_counter() - t0:.1f} s); contacts: {r.contacts}; min clearance after take-off "
             f"{r.min_clearance:.2f} m; frames taken without settling: {r.unsettled}")
    return 0
