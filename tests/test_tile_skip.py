"""mapper.skip_tiles: which tiles an iteration renders, the loss over them, and the mapper's bookkeeping."""

import numpy as np
import pytest
import torch

from flightrecon.checkpoint import load_checkpoint, save_checkpoint
from flightrecon.config import MapperConfig
from flightrecon.geometry import camera_pose
from flightrecon.mapping.losses import frame_target, training_loss
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.mapping.tile_skip import tile_errors, tiles_to_keep
from flightrecon.render.api import RenderOutput, tile_grid
from flightrecon.scenario import load_config
from flightrecon.scene.procedural import make_scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world

W, H = 72, 40  # 5 x 3 tiles, the last row and column partial


@pytest.fixture(scope="module")
def views():
    scene = make_scene("office0", 0)
    cam = RGBDCamera(build_world(scene, load_config(None), with_drone=False), W, H, 90.0, 0.05, 10.0)
    poses = [camera_pose([0.0, 0.0, 1.2], 0.5 + 0.2 * k, 20.0) for k in range(3)]
    return cam.K, [(*cam.render(T), T) for T in poses]


def _mapper(**kw) -> OnlineMapper:
    cfg = MapperConfig(backend="cpu", init_subsample=0.3, init_scale_by_resolution=False, **kw)
    return OnlineMapper(cfg, near=0.05, far=10.0, seed=0, device="cpu")


def test_tile_errors_sum_each_tiles_mean_color_error():
    g = torch.Generator().manual_seed(0)
    color, target = torch.rand(H, W, 3, generator=g), torch.rand(H, W, 3, generator=g)
    got = tile_errors(color, target)
    assert got.shape == tile_grid(W, H) == (3, 5)
    per_pixel = np.abs(color.numpy().astype(np.float64) - target.numpy()).mean(-1)
    for r in range(3):
        for c in range(5):
            assert got[r, c] == pytest.approx(per_pixel[16 * r:16 * r + 16, 16 * c:16 * c + 16].sum(), rel=1e-6)


def test_tiles_to_keep_leaves_out_the_lowest_errors_first_in_row_order_on_ties():
    errors = np.array([[3.0, 1.0, 5.0], [1.0, 0.0, 2.0]])
    assert tiles_to_keep(errors, 0.0).all()
    np.testing.assert_array_equal(tiles_to_keep(errors, 0.5), [[True, False, True], [False, False, True]])
    np.testing.assert_array_equal(tiles_to_keep(errors, 0.34), [[True, False, True], [True, False, True]])  # 2 of 6
    np.testing.assert_array_equal(tiles_to_keep(errors, 0.95), [[False, False, True], [False, False, False]])


def test_the_loss_over_kept_pixels_is_each_terms_mean_over_them():
    g = torch.Generator().manual_seed(1)
    rgb, color = torch.rand(H, W, 3, generator=g), torch.rand(H, W, 3, generator=g)
    depth, rendered_depth = torch.rand(H, W, 1, generator=g) + 1.0, torch.rand(H, W, 1, generator=g) + 1.0
    out = RenderOutput(features=color[None], alpha=torch.ones(1, H, W, 1), depth=rendered_depth[None],
                       normal=torch.zeros(1, H, W, 3), distortion=torch.rand(1, H, W, 1, generator=g))
    target = frame_target(rgb, depth, torch.ones(H, W, 3), with_ssim=False)
    keep = torch.zeros(H, W, 1, dtype=torch.bool)
    keep[:16, :32] = True
    k = keep[..., 0].numpy()
    none = dict(ssim_weight=0.0, lambda_depth=0.0, lambda_normal=0.0, lambda_distortion=0.0)
    l1 = float(training_loss(out, target, **none, keep=keep))
    assert l1 == pytest.approx(np.abs(color.numpy() - rgb.numpy())[k].mean(), rel=1e-5)
    assert float(training_loss(out, target, **none, keep=torch.ones_like(keep))) == pytest.approx(
        float(training_loss(out, target, **none)), rel=1e-6)
    depth_term = float(training_loss(out, target, **{**none, "lambda_depth": 1.0}, keep=keep)) - l1
    assert depth_term == pytest.approx(np.abs(rendered_depth.numpy() - depth.numpy())[k].mean(), rel=1e-4)
    dist_term = float(training_loss(out, target, **{**none, "lambda_distortion": 1.0}, keep=keep)) - l1
    assert dist_term == pytest.approx(out.distortion[0, ..., 0].numpy()[k].mean(), rel=1e-4)


def test_a_frames_iterations_leave_out_its_best_matched_tiles_and_render_all_every_nth(views):
    K, vs = views
    mapper = _mapper(k_new=7, k_replay=0, skip_tiles=0.4, skip_full_every=3)
    renders = []  # (keep_tiles, rendered color) of each training render: a spy that calls through
    render = mapper._render

    def spy(p, viewmats, Ks, width, height, outputs, keep_tiles=None):
        out = render(p, viewmats, Ks, width, height, outputs, keep_tiles)
        renders.append((keep_tiles, out.features[0].detach().clone()))
        return out

    mapper._render = spy
    mapper.add_frame(*vs[0][:2], K, vs[0][2])
    assert [k is None for k, _ in renders] == [True, False, False, True, False, False, True]
    target = mapper._target(mapper.frames[0]).rgb  # the frame as stored (8-bit color)
    tiles = 15
    for i in (1, 2, 4, 5):
        keep = renders[i][0][0].numpy()
        assert keep.sum() == tiles - round(0.4 * tiles)
        # brute force: the errors each tile had when last rendered, from the kept renders' own images
        errors = np.zeros((3, 5))
        last_full = max(j for j in range(i) if renders[j][0] is None)
        for j in range(last_full, i):
            img = np.abs(renders[j][1].numpy() - target.numpy()).mean(-1)
            rendered = np.ones((3, 5), bool) if renders[j][0] is None else renders[j][0][0].numpy()
            for r in range(3):
                for c in range(5):
                    if rendered[r, c]:
                        errors[r, c] = img[16 * r:16 * r + 16, 16 * c:16 * c + 16].sum()
        dropped = np.argsort(errors.ravel(), kind="stable")[:round(0.4 * tiles)]
        assert set(np.flatnonzero(~keep.ravel())) == set(dropped)
        pixels = np.repeat(np.repeat(keep, 16, 0), 16, 1)[:H, :W]
        assert (renders[i][1].numpy()[~pixels] == 0).all()  # the rasterizer drew nothing there


def test_skipping_tiles_resumes_from_a_checkpoint_exactly(views, tmp_path):
    K, vs = views
    settings = dict(k_new=5, k_replay=3, skip_tiles=0.5, skip_full_every=2)
    flown = _mapper(**settings)
    for v in vs[:2]:
        flown.add_frame(*v[:2], K, v[2])
    resumed = _mapper(**settings)
    save_checkpoint(tmp_path / "checkpoint.npz", flown.get_state())  # through the file, as a resumed flight
    resumed.set_state(load_checkpoint(tmp_path / "checkpoint.npz"))
    assert resumed.frame_iterations == flown.frame_iterations and resumed.frame_iterations[0] > 5
    for m in (flown, resumed):
        m.add_frame(*vs[2][:2], K, vs[2][2])
    for name in ("means", "colors", "opacity_logits"):
        assert torch.equal(resumed.map[name], flown.map[name]), name
    for a, b in zip(resumed.tile_error, flown.tile_error):
        np.testing.assert_array_equal(a, b)
