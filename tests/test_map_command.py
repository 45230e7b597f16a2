"""`flightrecon map` end to end on a small dataset recorded from MuJoCo views of office0."""

import json

import cv2
import pytest
from skimage.metrics import peak_signal_noise_ratio

from flightrecon.cli import main
from flightrecon.dataset import DatasetWriter
from flightrecon.geometry import camera_pose
from flightrecon.mapping.ply import load_map
from flightrecon.scenario import load_config
from flightrecon.scene.procedural import make_scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world

W, H = 64, 48


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    cam = RGBDCamera(build_world(make_scene("office0", 0), load_config(None), with_drone=False), W, H)
    wr = DatasetWriter(root, cam.K, W, H)
    for i in range(5):
        T = camera_pose([0.05 * i, 0.0, 1.2], 0.4 + 0.1 * i, 20.0)
        rgb, depth = cam.render(T)
        wr.add(rgb, depth, T, time=float(i))
    wr.close()
    return root


@pytest.mark.slow
def test_map_command_writes_map_metrics_and_renders(dataset, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["map", str(dataset), "--out", str(out), "--holdout", "5", "--set", "mapper.k_new=8",
               "--set", "mapper.k_replay=4", "--set", 'mapper.backend="cpu"'])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert (m["frames_train"], m["frames_test"]) == (4, 1)
    assert [v["frame"] for v in m["test"]["per_view"]] == ["frame_00004"]
    assert len(m["train"]["per_view"]) == 4
    gmap = load_map(out / "map.ply")
    assert len(gmap) == m["splats"] > 0
    assert set(gmap["frame_created"].tolist()) <= {0, 1, 2, 3}
    # the reported PSNR agrees with the written 8-bit renders (quantization aside)
    read = lambda p: cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) / 255.0  # noqa: E731
    ren, gt = read(out / "renders/frame_00004_color.png"), read(out / "renders/frame_00004_color_gt.png")
    assert abs(peak_signal_noise_ratio(gt, ren, data_range=1.0) - m["test"]["mean"]["psnr"]) < 0.5
    assert 0 < m["test"]["mean"]["depth_l1_cm"] < 100.0 and m["test"]["mean"]["views"] == 1
    assert "test (1 views)" in capsys.readouterr().out


def test_map_command_reports_a_missing_dataset(tmp_path, capsys):
    assert main(["map", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "transforms.json" in capsys.readouterr().err


def test_bench_map_reports_the_profile_and_thread_scaling(dataset, tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "map", "--dataset", str(dataset), "--set", "mapper.k_new=4", "--set", "mapper.k_replay=2",
                 "--scaling", "1,2", "--scaling-iterations", "2", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    row = result["rows"][0]
    assert row["ms_per_replay_iteration_1_threads"] > 0 and row["ms_per_replay_iteration_2_threads"] > 0
    prof = result["profiles"][dataset.name]
    assert sum(r["share"] for r in prof["stages"]) == pytest.approx(1.0)
    assert 0 < prof["blend"]["useful_of_ceiling"] <= prof["blend"]["of_ceiling"]
    assert result["ceiling"]["blend_per_s_thread"] > 0
