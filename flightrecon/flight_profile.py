"""Where a flight's time goes, frame by frame: `profile.csv` in every run folder, and its summary.

The loop times its own stages per frame (capture, mapping, selector update, planning, scoring,
rehearsing the chosen flight, simulated flight: frames.csv); the mapping's time is split further by
flightrecon.profiling's stage timers (forward and backward blend, SSIM, optimizer step, densify,
...). Those cost a few thousand clock reads per frame against seconds of mapping, so every flight
keeps them. `flightrecon profile
RUN` prints each stage's share of the loop's time over blocks of frames.
"""

from __future__ import annotations

import csv
from pathlib import Path

from flightrecon import profiling, run_folder
from flightrecon.errors import DataError

LOOP_STAGES = ("t_capture", "t_map", "t_select_update", "t_plan", "t_score", "t_rehearse", "t_fly_sim")


def _column(stage: str) -> str:
    return "map_" + "".join(c if c.isalnum() else "_" for c in stage).strip("_").replace("__", "_")


MAP_COLUMNS = {stage: _column(stage) for stage in profiling.ITERATION_STAGES + profiling.FRAME_STAGES}
PROFILE_COLUMNS = ("frame", *LOOP_STAGES, "map_iterations", *MAP_COLUMNS.values())


def mapping_columns(prof: profiling.StageProfile) -> dict[str, float]:
    """A frame's mapping profile as profile.csv columns: seconds per stage and the iterations run."""
    seconds = profiling.exclusive_seconds(prof)
    return {"map_iterations": prof.calls["render"], **{MAP_COLUMNS[k]: v for k, v in seconds.items()}}


def read_profile(run_dir: str | Path) -> list[dict[str, float]]:
    path = Path(run_dir) / run_folder.PROFILE
    if not path.is_file():
        raise DataError(f"{path}: no profile (flights write it since the per-frame profile was added; "
                        "fly the run again, or time it with `flightrecon bench run`)")
    with open(path, newline="") as fh:
        rows = [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(fh)]
    if not rows:
        raise DataError(f"{path}: no frames in the profile")
    return rows


def summary(rows: list[dict[str, float]], every: int) -> list[dict]:
    """Per stage, its seconds per frame and share of the loop's time over all frames and over each
    block of `every` frames: the loop's stages with mapping replaced by the mapping's own stages."""
    if every < 1:
        raise DataError(f"profile: --every must be at least 1, got {every}")
    rows = [{**r, "map_rest": r.get("t_map", 0.0) - sum(r.get(c, 0.0) for c in MAP_COLUMNS.values())}
            for r in rows]
    stages = [(name.removeprefix("t_"), name) for name in LOOP_STAGES if name != "t_map"]
    # the mapping's stages, and its time outside add_frame (the map's finiteness check)
    stages[1:1] = [(f"map: {stage}", column) for stage, column in MAP_COLUMNS.items()] + [("map: rest", "map_rest")]
    blocks = [("all", rows)] + [(f"{int(rows[i]['frame'])}-{int(rows[min(i + every, len(rows)) - 1]['frame'])}",
                                 rows[i:i + every]) for i in range(0, len(rows), every)]
    totals = {name: sum(r.get(stage, 0.0) for r in block for stage in LOOP_STAGES) for name, block in blocks}
    table = []
    for label, column in stages:
        entry: dict = {"stage": label, "s_per_frame": sum(r.get(column, 0.0) for r in rows) / len(rows)}
        for name, block in blocks:
            entry[f"share {name}"] = sum(r.get(column, 0.0) for r in block) / max(totals[name], 1e-12)
        table.append(entry)
    table.append({"stage": "loop total", "s_per_frame": totals["all"] / len(rows),
                  **{f"share {name}": 1.0 for name, _ in blocks}})
    return table
