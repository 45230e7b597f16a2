"""`flightrecon fly SCENARIO`: an active reconstruction flight (default), or `--survey`.

The default mode runs the closed loop of flightrecon.mission with the selector of
`selector.method` (2D GauSS-MI by default) and writes the run folder; `--resume RUN_DIR` continues
a killed run from its last checkpoint. The survey mode flies the scripted loop of
flightrecon.survey and writes an RGB-D dataset.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from flightrecon.config import ScenarioConfig
from flightrecon.errors import FlightReconError
from flightrecon.metric_defs import summary_line
from flightrecon.scenario import load_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fly", help="active reconstruction flight (--survey: scripted loop that writes a dataset)")
    p.add_argument("scenario", nargs="?", default=None, help="scenario TOML path or name in scenarios/")
    p.add_argument("--resume", metavar="RUN_DIR", default=None,
                   help="continue a killed active run from its checkpoint (its saved config is used)")
    p.add_argument("--allow-code-change", action="store_true",
                   help="with --resume: continue a run whose earlier frames were flown with other code "
                        "(refused otherwise; recorded in provenance.json)")
    p.add_argument("--survey", action="store_true", help="fly the scripted survey loop and write a dataset")
    p.add_argument("--out", default=None, help="output folder (default: <output.run_root>/<scenario>/<mode>/seed<k>)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set camera.width=320 (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--rerun", action="store_true",
                   help="stream the flight live to a rerun viewer (web viewer address printed when headless)")
    p.add_argument("--no-record", action="store_true", help="write no recording.rrd (output.record=false)")
    p.add_argument("--diagnose", action="store_true",
                   help="write diagnosis.csv: the chosen view's MI by kind of splat, the move, the surface seen so "
                        "far and each frame's overlap with earlier ones (output.diagnose=true)")
    p.add_argument("--export-dataset", action="store_true",
                   help="also keep the captured RGB-D frames and poses as a nerfstudio-style dataset in "
                        "<run>/dataset (transforms.json; output.dataset=true)")
    p.add_argument("--export-3dgs", action="store_true",
                   help="also write map_3dgs.ply with scale_2 for 3DGS viewers (as `map --export-3dgs`)")
    p.set_defaults(func=run)


def default_out_dir(cfg: ScenarioConfig, mode: str) -> Path:
    return Path(cfg.output.run_root) / cfg.name / mode / f"seed{cfg.seed}"


def run(args: argparse.Namespace) -> int:
    if args.resume:
        return _run_active(None, Path(args.resume), not args.quiet, args)
    if args.scenario is None:
        raise FlightReconError("fly needs a SCENARIO (or --resume RUN_DIR)")
    flags = ((["output.record=false"] if args.no_record else []) + (["output.diagnose=true"] if args.diagnose else [])
             + (["output.dataset=true"] if args.export_dataset else []))
    cfg = load_config(args.scenario, args.overrides + flags)
    progress = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    if args.survey:
        return _run_survey(cfg, Path(args.out) if args.out else default_out_dir(cfg, "survey"), progress)
    out = Path(args.out) if args.out else default_out_dir(cfg, cfg.selector.method)
    return _run_active(cfg, out, not args.quiet, args)


def _run_active(cfg: ScenarioConfig | None, out: Path, progress: bool, args: argparse.Namespace) -> int:
    from flightrecon.mission import Mission, outputs

    mission = Mission.resume(out, progress=progress) if cfg is None else Mission(cfg, out, progress=progress)
    mission.live_viewer = args.rerun
    mission.allow_code_change = args.allow_code_change
    m = mission.run()
    if args.export_3dgs:
        from flightrecon.mapping.ply import save_map

        save_map(mission.mapper.map, out / "map_3dgs.ply", for_3dgs=True)
    print(f"{m['frames']} frames, {m['splats']} splats ({m['map_mb']:.1f} MB); {_views(m['eval'])}: "
          f"{summary_line(m['eval'])}; flew {m['flight_distance_m']:.1f} m, {m['recoveries']} recoveries, "
          f"{m['contacts']} contacts, lowest clearance {_clearance(m)} -> {out}")
    margin = outputs.margin_record(mission.cfg, mission.state.records)
    if not margin.kept:
        print(f"{margin.warning()} (frames.csv, min_clearance)", file=sys.stderr)
    if m["contacts"]:
        print(contact_warning(m["contacts"], f"frames {m['contact_frames']}, listed in {out / 'events.log'}"),
              file=sys.stderr)
    return 0


def _clearance(m: dict) -> str:
    low = m["min_clearance_m"]
    return "n/a" if low is None else f"{low:.3f} m (margin {m['safety_margin_m']:g} m)"


def _views(ev: dict) -> str:
    """'evaluation views', with how many counted where some saw too little surface to count."""
    if not ev["views_dropped"]:
        return "evaluation views"
    return f"{ev['views']} evaluation views ({ev['views_dropped']} left out: no pose of theirs saw enough surface)"


def contact_warning(contacts: int, where: str) -> str:
    """The line that keeps a flight which touched the scene from reading like a clean result."""
    return (f"WARNING: the drone touched the scene {contacts} time(s) ({where}): this is not a collision-free "
            "flight (sim.on_contact = \"stop\" ends a flight at its first contact after take-off)")


def _run_survey(cfg: ScenarioConfig, out: Path, progress) -> int:
    from flightrecon.survey import run_survey

    t0 = time.perf_counter()
    r = run_survey(cfg, out, progress)
    progress(f"wrote {r.frames} frames to {r.dataset} ({r.flight_time:.1f} s of flight in "
             f"{time.perf_counter() - t0:.1f} s); contacts: {r.contacts}; min clearance after take-off "
             f"{r.min_clearance:.2f} m; frames taken without settling: {r.unsettled}")
    if r.contacts:
        print(contact_warning(r.contacts, "each listed in the progress lines without --quiet"), file=sys.stderr)
    return 0
