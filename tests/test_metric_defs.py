"""The one owner of metric names, units, directions and averaging (flightrecon.metric_defs):
its NaN policy on hand-computed rows, that every metric a table, figure or evaluation reports is
defined there, and that depth L1 reads in centimetres in the mapper's held-out evaluation and in the
run evaluation alike."""

import math

import pytest
import torch

from flightrecon.config import MapperConfig
from flightrecon.evaluation.views import EvaluationSet, view_metrics
from flightrecon.experiments import report, run_eval
from flightrecon.geometry import camera_pose
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.mapping.offline import evaluate_view
from flightrecon.metric_defs import METRICS, PSNR_MAX_DB, mean_metrics, select, summary_line
from flightrecon.scenario import load_config
from flightrecon.scene.procedural import make_scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world

NAN = math.nan


def test_a_nan_view_is_left_out_of_that_metric_only_and_the_views_used_are_counted():
    rows = [{"frame": "a", "psnr": 20.0, "psnr_covered": NAN, "depth_l1_cm": 1.0},
            {"frame": "b", "psnr": 30.0, "psnr_covered": 24.0, "depth_l1_cm": 3.0},
            {"frame": "c", "psnr": 25.0, "psnr_covered": 28.0, "depth_l1_cm": 2.0}]
    assert mean_metrics(rows) == {"psnr": 25.0, "psnr_covered": 26.0, "psnr_covered_views": 2,
                                  "depth_l1_cm": 2.0, "views": 3}


def test_a_metric_no_view_defines_is_nan_and_no_rows_give_no_means():
    m = mean_metrics([{"normal_err_deg": NAN, "ssim": 0.5}, {"normal_err_deg": NAN, "ssim": 0.7}])
    assert math.isnan(m["normal_err_deg"]) and m["normal_err_deg_views"] == 0
    assert m["ssim"] == pytest.approx(0.6) and "ssim_views" not in m and m["views"] == 2
    assert mean_metrics([]) == {"views": 0}


def test_metrics_read_with_their_unit_precision_and_direction():
    d = METRICS["depth_l1_cm"]
    assert (d.heading, d.format(2.0), d.describe(2.0)) == ("D-L1 [cm]", "2.00", "D-L1 2.00 cm")
    assert d.format(NAN) == "n/a" and d.format(None, missing="") == "" and d.describe(NAN) == "D-L1 n/a"
    assert METRICS["ssim"].heading == "SSIM" and METRICS["fscore"].format(0.95251) == "0.953"
    assert summary_line({"psnr": 23.607, "ssim": 0.81886, "depth_l1_cm": 2.2015}) == \
        "PSNR 23.61 dB, SSIM 0.819, D-L1 2.20 cm"
    assert sorted([24.0, 26.0, 25.0], key=METRICS["psnr"].sort_key) == [26.0, 25.0, 24.0]
    assert sorted([3.0, 1.0, 2.0], key=d.sort_key) == [1.0, 2.0, 3.0]
    with pytest.raises(KeyError, match="depth_l1"):
        select("psnr", "depth_l1")  # metres are not a reported unit


def test_every_metric_the_report_shows_is_defined_and_written_over_frames():
    tables = (report.OVERALL, report.PAIRED, report.PER_SCENE, report.RANKED, report.SNAPSHOT,
              report.OVER_FRAMES_FIGURE, run_eval.OVER_FRAMES)
    for table in tables:
        for m in table:
            assert METRICS[m.key] == m, m
    # the ranking and the mesh curves read eval_over_frames.csv: it must hold their columns
    written = {m.key for m in run_eval.OVER_FRAMES}
    assert {m.key for m in report.RANKED + report.SNAPSHOT} <= written


def test_every_numeric_entry_of_the_view_metrics_is_defined():
    H, W = 16, 20
    color = torch.full((H, W, 3), 0.5)
    depth = torch.full((H, W, 1), 2.0)
    alpha = torch.ones(H, W, 1)
    m = view_metrics(color, depth, alpha, color * 0.9, depth + 0.01)
    assert set(m) <= set(METRICS), set(m) - set(METRICS)
    assert m["depth_l1_cm"] == pytest.approx(1.0, abs=1e-4)


@pytest.fixture(scope="module")
def rendered_map():
    """A map initialized from one simulator frame (no optimization) and its render at that pose."""
    W, H = 48, 36
    cam = RGBDCamera(build_world(make_scene("office0", 0), load_config(None), with_drone=False), W, H, 90.0, 0.05, 10.0)
    T = camera_pose([0.0, 0.0, 1.2], 0.5, 20.0)
    rgb, depth = cam.render(T)
    mapper = OnlineMapper(MapperConfig(backend="cpu", k_new=0, k_replay=0, init_scale_by_resolution=False),
                          near=0.05, far=10.0, seed=0, device="cpu")
    mapper.add_frame(rgb, depth, cam.K, T)
    out = mapper.render_view(T, cam.K, W, H, outputs=("features", "alpha", "depth"))
    return mapper, cam.K, T, out.features[0].clamp(0, 1), out.depth[0]


def test_a_2cm_depth_offset_reads_2_cm_in_the_mapper_and_the_run_evaluation(rendered_map):
    """Ground truth 2 cm behind the map's own rendered depth at every pixel: |offset| = 0.02 m = 2 cm."""
    mapper, K, T, color, depth = rendered_map
    truth = depth + 0.02
    held_out, _, _ = evaluate_view(mapper, color.numpy(), truth[..., 0].numpy(), K, T)
    H, W = depth.shape[:2]
    run = EvaluationSet(T[None], color[None], truth[None], K, W, H).evaluate(mapper)
    assert held_out["depth_l1_cm"] == pytest.approx(2.0, abs=1e-3)
    assert run["depth_l1_cm"] == pytest.approx(2.0, abs=1e-3)
    assert run["depth_l1_cm_covered"] == pytest.approx(2.0, abs=1e-3) and run["views"] == 1
    # the color is the map's own: zero error scores the cap, not infinity
    assert held_out["psnr"] == pytest.approx(PSNR_MAX_DB) and run["psnr"] == pytest.approx(PSNR_MAX_DB)
    assert run["psnr_covered"] == pytest.approx(PSNR_MAX_DB) and run["views_dropped"] == 0
