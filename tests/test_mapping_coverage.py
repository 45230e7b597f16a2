"""Held-out coverage (which pixels a training view saw, and how sharply) on analytic wall scenes."""

import numpy as np

from flightrecon.dataset import Frame
from flightrecon.mapping.offline import masked_metrics, training_coverage

W, H = 40, 30
K = np.array([[20.0, 0, 20], [0, 20.0, 15], [0, 0, 1]])


def _frame(depth: np.ndarray, z_offset: float = 0.0) -> Frame:
    """A camera on the z axis looking down +z at a wall; `z_offset` moves it back along the axis."""
    T = np.eye(4)
    T[2, 3] = -z_offset
    return Frame(np.zeros((H, W, 3), np.float32), depth.astype(np.float32), K, T, T, 0.0, "f")


def test_coverage_counts_seen_unoccluded_and_sharp_enough_pixels():
    wall = np.full((H, W), 2.0)
    view = _frame(wall)
    half = wall.copy()
    half[:, W // 2:] = 0.0  # the training frame's depth is invalid on the right half: nothing seen there
    occluded = wall.copy()
    occluded[5:10, 5:10] = 1.0  # something in front of the wall hides these pixels' surface
    cov = training_coverage(view, [_frame(half)])
    assert cov[:, : W // 2].all() and not cov[:, W // 2:].any()
    cov = training_coverage(view, [_frame(occluded)])
    assert not cov[5:10, 5:10].any() and cov.sum() == W * H - 25
    # The same wall from twice as far: its centre is seen (at half the resolution), not sharply enough.
    far = _frame(np.full((H, W), 4.0), z_offset=2.0)
    assert training_coverage(view, [far], max_footprint=np.inf)[10:20, 12:28].all()
    assert not training_coverage(view, [far]).any()
    assert training_coverage(view, [far], max_footprint=2.0 + 1e-6)[10:20, 12:28].all()


def test_masked_metrics_use_only_the_masked_pixels():
    rng = np.random.default_rng(0)
    rgb = rng.random((H, W, 3))
    color = rgb.copy()
    color[:, : W // 2] += 0.1  # error on the left half only
    depth = np.full((H, W), 2.0)
    rendered = depth.copy()
    rendered[:, : W // 2] += 0.05
    right = np.zeros((H, W), bool)
    right[:, W // 2:] = True
    m = masked_metrics(color, rendered, rgb, depth, ~right)
    assert abs(m["psnr"] - 20.0) < 1e-9 and abs(m["depth_l1_cm"] - 5.0) < 1e-10
    exact = masked_metrics(color, rendered, rgb, depth, right)
    assert exact["psnr"] == 60.0 and exact["depth_l1_cm"] == 0.0  # zero error: the documented 60 dB cap
    assert np.isnan(masked_metrics(color, rendered, rgb, depth, np.zeros((H, W), bool))["psnr"])
