"""The benchmark command: it runs end to end on a tiny map and flags contended timings."""

from __future__ import annotations

import json

from flightrecon.bench.common import contention_warning, machine
from flightrecon.cli import main


def test_contention_warning_only_when_load_exceeds_cores():
    assert contention_warning({"cores": 2, "load_avg_1m": 2.3}) is None
    warning = contention_warning({"cores": 2, "load_avg_1m": 4.1})
    assert warning is not None and "4.1" in warning
    assert "load_avg_1m" in machine()


def test_bench_render_reports_every_workload_with_its_peer(tmp_path):
    out = tmp_path / "render.json"
    rc = main(["bench", "render", "--sizes", "2000", "--repeat", "1", "--batch", "3",
               "--ref-pixels", "300", "--out", str(out)])
    assert rc == 0
    result = json.loads(out.read_text())
    rows = result["rows"]
    workloads = {(r["image"], r["workload"].split(" (")[0]) for r in rows}
    for image in ("640x480", "160x120"):
        for w in ("forward", "forward+backward", "reference forward"):
            assert (image, w) in workloads
    assert ("160x120", "3-camera 1-channel batch") in workloads
    assert all(r["ms"] > 0 for r in rows)
    # the peer ran on the same inputs in the same run: its ratio is reported
    assert all(r["speedup_vs_ref"] > 0 for r in rows if r["workload"].startswith("reference"))
    assert result["machine"]["cores"] >= 1
    stamp = result["provenance"]  # the commit, CPU and packages the figures came from
    assert "commit" in stamp and stamp["cpu"]["model"] and stamp["packages"]["torch"]


def test_bench_run_then_score_on_its_map(tmp_path):
    """bench run flies a whole (tiny) run into a kept folder; bench score restores its checkpoint and
    times exact and culled 2D GauSS-MI scoring and the baselines' on the same library."""
    run_dir = tmp_path / "run"
    tiny = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
            "mapper.k_new=6", "mapper.k_replay=2", "evaluation.views=2", "evaluation.every=0",
            "budget.initial_views=2"]
    sets = [a for s in tiny for a in ("--set", s)]
    out = tmp_path / "run.json"
    assert main(["bench", "run", "--scenario", "demo", "--frames", "4", "--run-dir", str(run_dir), *sets,
                 "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert {r["stage"] for r in result["rows"]} >= {"map", "select_update", "plan", "score"}
    assert result["splats"] > 0 and result["map_mb"] > 0 and result["wall_time_min"] > 0
    assert (run_dir / "metrics.json").is_file()
    profile = {r["stage"]: r for r in result["map_profile"]}
    assert profile["forward blend"]["ms_per_iteration"] > 0 and profile["densify"]["ms_per_frame"] > 0
    out = tmp_path / "score.json"
    assert main(["bench", "score", "--run", str(run_dir), "--sizes", "40x30", "--repeat", "1", "--threads", "1,2",
                 "--out", str(out)]) == 0
    score = json.loads(out.read_text())
    assert [r["threads"] for r in score["rows"]] == [1, 2]
    row = score["rows"][0]
    assert row["candidates"] > 20 and row["same_argmax"] and 1 <= row["rescored"] <= row["candidates"]
    assert 0 < row["binned_per_cand"] <= row["projected_per_cand"] and row["tests_per_cand"] > 0
    assert {b["method"] for b in score["baselines"]} == {"gaussmi", "fisherrf", "activegs"}
    activegs = next(b for b in score["baselines"] if b["method"] == "activegs")
    assert activegs["voxels_explored"] > 0  # its exploration utility is timed with the run's voxel map
    assert all(b["ratio_to_ours"] > 0 for b in score["baselines"])
