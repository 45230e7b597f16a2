"""tools/mapping_ceiling.py on a real tiny flight: the restored map scores what the flight measured,
the extra budget is counted in the flight's own iterations, and a rerun measures nothing twice."""

import csv
import importlib.util
from pathlib import Path

import pytest

from flightrecon.experiments.sweep import execute, plan_runs

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=4", "mapper.k_replay=2", "budget.frames=3", "budget.initial_views=1",
        "evaluation.views=2", "evaluation.every=1", "metrics.tsdf_voxel=0.05", "metrics.tsdf_truncation=0.15",
        "metrics.sample_points=5000"]


def _tool():
    path = Path(__file__).resolve().parents[1] / "tools" / "mapping_ceiling.py"
    spec = importlib.util.spec_from_file_location("mapping_ceiling", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_ceiling_restores_the_flight_and_adds_multiples_of_its_budget(tmp_path):
    (spec,) = plan_runs("demo", ["room0"], ["random"], 1, TINY, str(tmp_path))
    execute([spec], log=lambda s: None)
    out = tmp_path / "ceiling.csv"
    tool = _tool()
    tool.ceiling(spec.run_dir, [1.0, 2.0], out)
    rows = _rows(out)
    assert [r["extra_budget"] for r in rows] == ["0", "1", "2"]
    flown = _rows(spec.run_dir / "frames.csv")
    assert float(rows[0]["psnr"]) == pytest.approx(float(flown[-1]["eval_psnr"]), abs=1e-3)
    assert [int(r["extra_iterations"]) for r in rows] == [0, 3 * 6, 2 * 3 * 6]
    assert float(rows[2]["psnr"]) > float(rows[0]["psnr"])  # more iterations on the same views fit them better
    tool.ceiling(spec.run_dir, [1.0, 2.0, 4.0], out)  # resumed: only the new budget is measured
    assert [r["extra_budget"] for r in _rows(out)] == ["0", "1", "2", "4"]
