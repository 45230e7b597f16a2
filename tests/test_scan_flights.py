"""12-frame flights with no scene flag in scan-like meshes of four kinds (tests/scan_corpus.py): a
scan in its first camera's frame with holes, no ceiling and furniture at the default take-off (at
the CPU default's 320x240, so the frames it streams in flight are reduced to planner.look_width);
one in a camera frame with a partial ceiling; one stored -y-up without a ceiling; one z-up with
furniture where the drone would take off. Each: no contact, the flight keeps its safety margin (its
lowest clearance to the true scene, printed, is at least planner.safety_margin), the drone moves, and
the evaluation is finite with the views that saw no surface left out and counted."""

import csv
import json
import math

import numpy as np
import pytest

from flightrecon.mission import Mission
from flightrecon.scenario import load_config
from flightrecon.scene.scanify import ScanOptions, scan_procedural, write_scan
from scan_corpus import scan_corpus

SMALL = ["camera.width=160", "camera.height=120", "selector.scoring_width=80", "selector.scoring_height=60",
         "mapper.k_new=10", "mapper.k_replay=5", "budget.frames=12", "evaluation.views=16", "evaluation.every=0",
         "output.record=false"]
CORPUS = ["office0-seed4-camera.obj", "room0-seed0-camera.ply", "room2-seed3-z-up.ply"]
AT_320 = {"office0-seed4-camera.obj": ["camera.width=320", "camera.height=240", "selector.scoring_width=160",
                                       "selector.scoring_height=120"]}


@pytest.fixture(scope="module")
def meshes(tmp_path_factory) -> dict:
    by_name = {r.path.name: r.path for r in scan_corpus()}
    out = {name: by_name[name] for name in CORPUS}
    path = tmp_path_factory.mktemp("scan") / "room1-minus-y-up.ply"  # the corpus' -y-up scans are in mm
    write_scan(scan_procedural("room1", 3, ScanOptions(convention="-y-up", furniture=True, ceiling="none",
                                                       holes=4, frames=60, voxel=0.04, max_faces=60000)), path)
    out[path.name] = path
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", CORPUS + ["room1-minus-y-up.ply"])
def test_a_flight_in_a_scan_is_clean_moves_and_evaluates(meshes, name, tmp_path):
    cfg = load_config("default", SMALL + AT_320.get(name, []) + [f"scene.path={meshes[name]}"])
    metrics = Mission(cfg, tmp_path, progress=False).run()
    with open(tmp_path / "frames.csv") as f:
        clearance = [float(r["min_clearance"]) for r in csv.DictReader(f) if r["min_clearance"] not in ("", "nan")]
    ev = metrics["eval"]
    print(name, json.dumps({"distance_m": round(metrics["flight_distance_m"], 2), "recoveries": metrics["recoveries"],
                            "contacts": metrics["contacts"], "lowest_clearance_m": round(min(clearance), 3),
                            "psnr": round(ev["psnr"], 2), "depth_l1_cm": round(ev["depth_l1_cm"], 2),
                            "views": ev["views"], "views_dropped": ev["views_dropped"]}))
    assert metrics["contacts"] == 0
    assert min(clearance) >= cfg.planner.safety_margin and metrics["margin_breach_frames"] == []
    assert metrics["flight_distance_m"] > 1.0
    assert ev["views"] >= cfg.evaluation.views // 2 and ev["views"] + ev["views_dropped"] == cfg.evaluation.views
    assert all(math.isfinite(ev[k]) for k in ("psnr", "ssim", "depth_l1_cm"))
    assert np.isfinite(metrics["sim_time_s"])
