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
