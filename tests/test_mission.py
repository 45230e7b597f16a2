"""Closed-loop active flights end to end: real MuJoCo, OMPL, ruckig and the C++ rasterizer.

Tiny settings (80x60 camera, few iterations) keep each flight to seconds of compute on 2 cores.
"""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from flightrecon.cli import main
from flightrecon.errors import FlightReconError
from flightrecon.flight_profile import MAP_COLUMNS, read_profile
from flightrecon.mapping.ply import load_map
from flightrecon.mission import Mission
from flightrecon.scenario import load_config

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=8", "mapper.k_replay=4", "evaluation.views=3", "evaluation.every=1"]


def _rows(run_dir: Path) -> list[dict]:
    with open(run_dir / "frames.csv") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_short_flight_improves_and_writes_outputs(tmp_path, capsys):
    cfg = load_config("demo", TINY + ["budget.frames=6", "budget.initial_views=3"])
    metrics = Mission(cfg, tmp_path, progress=False).run()
    for name in ("config.toml", "frames.csv", "profile.csv", "map.ply", "metrics.json", "trajectory.csv",
                 "events.log", "checkpoint.npz"):
        assert (tmp_path / name).is_file(), name
    rows = _rows(tmp_path)
    # the profile splits each frame's mapping time into its stages, without counting any twice
    profile = read_profile(tmp_path)
    assert [int(r["frame"]) for r in profile] == list(range(6))
    for frame, p in zip(rows, profile):
        stages = sum(p[c] for c in MAP_COLUMNS.values())
        assert p["map_iterations"] == 8 + 4 and min(p[c] for c in MAP_COLUMNS.values()) > -1e-3
        assert 0.8 * float(frame["t_map"]) < stages <= float(frame["t_map"])
        assert p["t_map"] == pytest.approx(float(frame["t_map"]), rel=1e-5)
    assert main(["profile", str(tmp_path), "--every", "3"]) == 0
    printed = capsys.readouterr().out
    assert "| map: forward blend |" in printed and "share 0-2" in printed and "share 3-5" in printed
    assert [int(r["frame"]) for r in rows] == list(range(6))
    psnr = [float(r["eval_psnr"]) for r in rows]
    dl1 = [float(r["eval_depth_l1_cm"]) for r in rows]
    assert psnr[-1] > psnr[0] + 1.0, psnr
    assert dl1[-1] < dl1[0], dl1
    assert metrics["contacts"] == 0
    # the margin is kept, and metrics.json says so from frames.csv
    flown = [float(r["min_clearance"]) for r in rows if r["min_clearance"] not in ("", "nan")]
    assert metrics["min_clearance_m"] == pytest.approx(min(flown), abs=1e-5)
    assert metrics["min_clearance_m"] >= cfg.planner.safety_margin
    assert metrics["margin_breach_frames"] == [] and metrics["safety_margin_m"] == cfg.planner.safety_margin
    assert int(rows[-1]["n_splats"]) == metrics["splats"] == len(load_map(tmp_path / "map.ply"))
    selected = [r for r in rows[2:-1] if r["n_feasible"] and int(r["n_feasible"]) > 1]
    assert selected, "no step had a choice between candidates"
    assert all(np.isfinite(float(r["chosen_score"])) for r in selected)
    ema = [float(r["reliable_share_ema"]) for r in rows]  # GauSS-MI's stopping statistic
    assert all(0.0 <= e <= 1.0 for e in ema) and ema[-1] > 0


@pytest.mark.slow
def test_stopping_rule_ends_the_flight_early(tmp_path):
    # Splats fit the frames they came from, so the reliable share rises and its EMA passes 75% well
    # before the 40-frame budget.
    cfg = load_config("demo", TINY + ["budget.frames=40", "budget.initial_views=2", "budget.stop_on_reliability=true",
                                      "evaluation.every=0"])
    metrics = Mission(cfg, tmp_path, progress=False).run()
    rows = _rows(tmp_path)
    assert metrics["frames"] == len(rows) < 40
    assert float(rows[-1]["reliable_share_ema"]) > 0.75
    assert "stopping rule met" in (tmp_path / "events.log").read_text()


def _fly(args: list[str], **kw) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "flightrecon.cli", "fly", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


@pytest.mark.slow
def test_kill_and_resume_equals_uninterrupted(tmp_path):
    extra = ["budget.frames=5", "budget.initial_views=2", "evaluation.every=0", "output.ply_extras=true",
             "mapper.prune_opacity=0.5"]  # prunes every frame: the resumed run must prune and reseed alike
    sets = [a for s in TINY + extra for a in ("--set", s)]
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    p = _fly(["demo", "--quiet", "--out", str(whole), *sets])
    assert p.wait(timeout=600) == 0, p.stdout.read()
    p = _fly(["demo", "--quiet", "--out", str(broken), *sets])
    deadline = time.time() + 600
    while time.time() < deadline:  # kill it as soon as two frames are checkpointed
        if (broken / "frames.csv").is_file() and len(_rows(broken)) >= 2 and p.poll() is None:
            p.send_signal(signal.SIGKILL)
            break
        if p.poll() is not None:
            break
        time.sleep(0.05)
    p.wait(timeout=60)
    assert p.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    assert not (broken / "metrics.json").exists()
    p = _fly(["--resume", str(broken), "--quiet"])
    assert p.wait(timeout=600) == 0, p.stdout.read()
    a, b = load_map(whole / "map.ply"), load_map(broken / "map.ply")
    for name in ("means", "quats", "log_scales", "opacity_logits", "colors", "reliability"):
        assert np.array_equal(a[name].numpy(), b[name].numpy()), name
    ma, mb = (json.loads((d / "metrics.json").read_text()) for d in (whole, broken))
    assert ma["eval"] == mb["eval"] and ma["flight_distance_m"] == mb["flight_distance_m"]
    assert ma["splats_pruned"] == mb["splats_pruned"] > 0
    keys = ("frame", "sim_time", "n_splats", "n_feasible", "chosen_score", "flight_distance")
    assert [[r[k] for k in keys] for r in _rows(whole)] == [[r[k] for k in keys] for r in _rows(broken)]
    assert [r["map_iterations"] for r in read_profile(broken)] == [r["map_iterations"] for r in read_profile(whole)]


def test_resume_of_a_folder_without_a_run_names_it(tmp_path):
    with pytest.raises(FlightReconError, match="config.toml"):
        Mission.resume(tmp_path)


def test_unknown_method_names_the_key():
    from flightrecon.active.registry import make_selector

    with pytest.raises(FlightReconError, match="selector.method"):
        make_selector(load_config("demo", ["selector.method=nope"]))


@pytest.mark.slow
def test_a_non_finite_map_names_the_frame_the_stage_and_the_column(tmp_path):
    from flightrecon.errors import DataError

    cfg = load_config("demo", TINY + ["budget.frames=3", "budget.initial_views=3"])
    mission = Mission(cfg, tmp_path, progress=False)
    mission.step()
    mission.mapper.map["quats"][7] = float("nan")
    with pytest.raises(DataError, match=r"^frame 1, stage mapping: render: quats contains NaN or inf"):
        mission.step()
    mission.mapper.map["quats"][7] = 1.0
    mission.selector.reliability(mission.view)[4, 1] = float("inf")
    with pytest.raises(DataError, match=r"map column 'reliability' holds NaN or inf at 1 of \d+ splats \(first: splat 4\)"):
        mission.mapper.map.check_finite()
