"""`flightrecon plan-study`: a small sweep writes consistent CSV, Markdown and figure; bad input exits 2."""

from __future__ import annotations

import csv

import pytest

from flightrecon.cli import main


@pytest.mark.slow
def test_small_sweep_writes_table_and_figure(tmp_path):
    rc = main(["plan-study", "demo", "--vel", "0.5,1.5", "--acc", "2.0", "--margin", "0.05,0.3",
               "--poses", "2", "--fly", "1", "--out", str(tmp_path)])
    assert rc == 0
    rows = list(csv.DictReader((tmp_path / "study.csv").open()))
    assert len(rows) == 4
    by = {(float(r["max_vel"]), float(r["safety_margin"])): r for r in rows}
    for r in rows:
        assert 0.0 < float(r["share_feasible"]) <= 1.0
        assert int(r["contacts"]) == 0 and float(r["min_clearance_m"]) > 0.0
    # A wider margin can only remove candidates; the same candidates at a higher speed are no slower.
    for v in (0.5, 1.5):
        assert float(by[(v, 0.3)]["share_feasible"]) <= float(by[(v, 0.05)]["share_feasible"])
    assert float(by[(1.5, 0.05)]["duration_max_s"]) <= float(by[(0.5, 0.05)]["duration_max_s"]) + 1e-9
    md = (tmp_path / "study.md").read_text()
    assert md.count("\n| default |") == 4
    assert (tmp_path / "figures" / "plan_study.png").stat().st_size > 10_000


def test_bad_sweep_value_is_a_clear_error(tmp_path, capsys):
    assert main(["plan-study", "demo", "--vel", "fast", "--out", str(tmp_path)]) == 2
    assert "--vel" in capsys.readouterr().err
    assert main(["plan-study", "demo", "--margin", "5", "--out", str(tmp_path)]) == 2
    assert "planner.safety_margin" in capsys.readouterr().err
