"""Dataset writer/reader: round trip, nerfstudio axes, and clear errors for broken files."""

import json

import numpy as np
import pytest

from flightrecon.dataset import DatasetWriter, load_dataset, read_trajectory_csv
from flightrecon.errors import DataError
from flightrecon.geometry import camera_pose, intrinsics


def _write(tmp_path, n=3, w=32, h=24, noisy=False):
    rng = np.random.default_rng(0)
    K = intrinsics(w, h, 90.0)
    wr = DatasetWriter(tmp_path, K, w, h)
    frames = []
    for i in range(n):
        rgb = rng.random((h, w, 3)).astype(np.float32)
        depth = rng.uniform(0.2, 9.0, (h, w)).astype(np.float32)
        depth[0, :3] = [0.0, np.nan, 70.0]  # invalid, NaN, beyond 16-bit mm -> all stored as 0
        T = camera_pose(np.array([i, 1.0, 1.5]), yaw=0.3 * i, pitch_deg=10.0)
        T_true = T.copy()
        if noisy:
            T_true[:3, 3] += 0.01
        wr.add(rgb, depth, T, time=0.5 * i, T_wc_true=T_true)
        frames.append((rgb, depth, T, T_true))
    wr.close({"t": np.arange(5) * 0.1, "x": np.linspace(0, 1, 5)})
    return K, frames


def test_round_trip(tmp_path):
    K, frames = _write(tmp_path)
    ds = load_dataset(tmp_path)
    assert len(ds) == 3 and (ds.width, ds.height) == (32, 24)
    for f, (rgb, depth, T, _) in zip(ds, frames):
        assert f.rgb.dtype == np.float32 and f.depth.dtype == np.float32
        assert np.abs(f.rgb - rgb).max() <= 0.5 / 255 + 1e-6
        ok = np.isfinite(depth) & (depth > 0) & (depth < 65.0)
        assert np.abs(f.depth[ok] - depth[ok]).max() <= 0.0005 + 1e-6
        assert np.all(f.depth[~ok] == 0)
        np.testing.assert_allclose(f.T_wc, T, atol=1e-12)
        np.testing.assert_allclose(f.T_wc_true, T, atol=1e-12)
        np.testing.assert_allclose(f.K, K)
    np.testing.assert_allclose(ds.poses[1], frames[1][2])
    traj = ds.trajectory()
    np.testing.assert_allclose(traj["x"], np.linspace(0, 1, 5))


def test_index_uses_nerfstudio_opengl_axes(tmp_path):
    """nerfstudio's camera looks along its -z column with +y up: check against the OpenCV pose."""
    _, frames = _write(tmp_path)
    index = json.loads((tmp_path / "transforms.json").read_text())
    assert index["camera_model"] == "OPENCV" and index["depth_unit_scale_factor"] == 0.001
    assert index["frames"][0]["depth_file_path"] == "depth/frame_00000.png"
    for e, (_, _, T, _) in zip(index["frames"], frames):
        M = np.array(e["transform_matrix"])
        np.testing.assert_allclose(-M[:3, 2], T[:3, 2], atol=1e-12)  # viewing direction
        np.testing.assert_allclose(M[:3, 1], -T[:3, 1], atol=1e-12)  # image up
        np.testing.assert_allclose(M[:3, 3], T[:3, 3])


def test_noisy_poses_keep_the_true_pose(tmp_path):
    _write(tmp_path, noisy=True)
    f = load_dataset(tmp_path)[2]
    np.testing.assert_allclose(f.T_wc_true[:3, 3] - f.T_wc[:3, 3], 0.01, atol=1e-12)


@pytest.mark.parametrize("damage", ["missing_index", "bad_json", "corrupt_png", "missing_depth",
                                    "nan_pose", "bad_csv"])
def test_broken_files_name_the_file(tmp_path, damage):
    _write(tmp_path)
    if damage == "missing_index":
        (tmp_path / "transforms.json").unlink()
        with pytest.raises(DataError, match="transforms.json"):
            load_dataset(tmp_path)
    elif damage == "bad_json":
        (tmp_path / "transforms.json").write_text('{"fl_x": 3')
        with pytest.raises(DataError, match="transforms.json"):
            load_dataset(tmp_path)
    elif damage == "nan_pose":
        idx = json.loads((tmp_path / "transforms.json").read_text())
        idx["frames"][1]["transform_matrix"][0][3] = float("nan")
        (tmp_path / "transforms.json").write_text(json.dumps(idx))
        with pytest.raises(DataError, match="transforms.json"):
            load_dataset(tmp_path)
    elif damage == "corrupt_png":
        (tmp_path / "images" / "frame_00001.png").write_bytes(b"\x89PNG garbage")
        ds = load_dataset(tmp_path)
        ds[0]
        with pytest.raises(DataError, match="frame_00001.png"):
            ds[1]
    elif damage == "missing_depth":
        (tmp_path / "depth" / "frame_00002.png").unlink()
        with pytest.raises(DataError, match="depth/frame_00002.png"):
            load_dataset(tmp_path)[2]
    elif damage == "bad_csv":
        (tmp_path / "trajectory.csv").write_text("t,x\n0.0,abc\n")
        with pytest.raises(DataError, match="trajectory.csv"):
            read_trajectory_csv(tmp_path / "trajectory.csv")


def test_writer_rejects_wrong_size_and_nan_pose(tmp_path):
    wr = DatasetWriter(tmp_path, intrinsics(8, 6, 90.0), 8, 6)
    with pytest.raises(DataError, match="8x6"):
        wr.add(np.zeros((5, 8, 3)), np.zeros((5, 8)), np.eye(4))
    with pytest.raises(DataError, match="NaN"):
        wr.add(np.zeros((6, 8, 3)), np.zeros((6, 8)), np.full((4, 4), np.nan))
