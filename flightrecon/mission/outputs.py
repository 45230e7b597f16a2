"""What a flight writes besides its map and checkpoint: frames.csv, profile.csv, events.log and
diagnosis.csv after every frame, metrics.json at the end.

Files are written whole and atomically (fileio), so a killed run never leaves a torn one.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from flightrecon import provenance, run_folder
from flightrecon.config import ScenarioConfig
from flightrecon.fileio import write_json, write_text
from flightrecon.flight_profile import LOOP_STAGES, PROFILE_COLUMNS
from flightrecon.mission.state import MissionState
from flightrecon.sim.safety import MarginRecord

FRAME_COLUMNS = ("frame", "sim_time", "t_capture", "t_map", "t_select_update", "t_plan", "t_score",
                 "t_rehearse", "t_fly_sim", "n_splats", "n_candidates", "n_feasible", "n_ompl",
                 "n_tracking_rejected", "chosen_score", "flight_time", "flight_distance", "recovery",
                 "frame_psnr", "frame_depth_l1_cm", "eval_psnr", "eval_depth_l1_cm", "min_clearance", "contacts",
                 "reliable_share_ema", "threads")


def save_frame_outputs(run_dir: Path, state: MissionState) -> None:
    """frames.csv, profile.csv and events.log as they stand, and diagnosis.csv when output.diagnose
    keeps rows."""
    write_text(run_dir / run_folder.FRAMES, _csv_text(state.records, FRAME_COLUMNS))
    write_text(run_dir / run_folder.PROFILE, _csv_text(state.records, PROFILE_COLUMNS))
    write_text(run_dir / run_folder.EVENTS, "".join(e + "\n" for e in state.events))
    if state.diagnosis:
        names = list(dict.fromkeys(k for r in state.diagnosis for k in r))
        write_text(run_dir / run_folder.DIAGNOSIS, _csv_text(state.diagnosis, names))


def write_metrics(run_dir: Path, cfg: ScenarioConfig, state: MissionState, final: dict, splats: int,
                  pruned: int, sim_time: float, contacts: int) -> dict:
    """metrics.json of a finished flight (its map.ply written already, for its size); returns it."""
    rec = state.records
    metrics = {
        "scenario": cfg.name, "method": cfg.selector.method, "seed": cfg.seed,
        "code_states": provenance.code_states(run_dir),
        "frames": len(rec), "splats": splats, "splats_pruned": pruned,
        "map_mb": (run_dir / run_folder.MAP).stat().st_size / 1e6,
        "flight_distance_m": state.flight_distance, "sim_time_s": sim_time,
        "wall_time_s": state.wall_time, "contacts": contacts,
        "contact_frames": _contact_frames(rec),
        **margin_record(cfg, rec).to_dict(),
        "recoveries": sum(1 for r in rec if r.get("recovery")),
        "eval": final,
        "mean_times_s": {k: float(np.mean([r[k] for r in rec if k in r]))
                         for k in LOOP_STAGES if any(k in r for r in rec)},
    }
    write_json(run_dir / run_folder.METRICS, metrics)
    return metrics


def margin_record(cfg: ScenarioConfig, rows: list[dict]) -> MarginRecord:
    """Where the flight of `rows` (frames.csv's) kept planner.safety_margin and where it did not."""
    return MarginRecord.of([r["frame"] for r in rows], [r.get("min_clearance", math.nan) for r in rows],
                           cfg.planner.safety_margin)


def plain(row: dict) -> dict:
    """A row with numpy scalars as Python ones: what checkpoints store, and how the CSV prints them."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}


def _contact_frames(rows: list[dict]) -> list[int]:
    """Frames whose flight touched the scene (frame 0's includes the take-off): where the running
    count of contacts in frames.csv grows."""
    frames, seen = [], 0
    for r in rows:
        if r.get("contacts", seen) > seen:
            frames.append(r["frame"])
            seen = r["contacts"]
    return frames


def _csv_text(rows: list[dict], columns) -> str:
    """Rows as CSV with the given columns (others ignored, missing ones empty), floats to 6 digits."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), restval="", extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()
