"""Online optimization on MuJoCo RGB-D views of a procedural scene, with the C++ rasterizer."""

import copy
import dataclasses
import logging

import numpy as np
import pytest
import torch

from flightrecon.config import MapperConfig
from flightrecon.geometry import camera_pose
from flightrecon.geometry import pixel_rays
from flightrecon.mapping.frames import BLOCK_DEPTH_SPREAD, Window, downsample, scaled_intrinsics, window_intrinsics
from flightrecon.mapping.image_metrics import depth_l1
from flightrecon.mapping.mapper import TRAIN_OUTPUTS, OnlineMapper, seed_share
from flightrecon.mapping.voxel_hash import voxel_keys
from flightrecon.scenario import load_config
from flightrecon.scene.procedural import make_scene
from flightrecon.sim.camera import RGBDCamera
from flightrecon.sim.world import build_world

W, H = 96, 72


@pytest.fixture(scope="module")
def views():
    scene = make_scene("office0", 0)
    cam = RGBDCamera(build_world(scene, load_config(None), with_drone=False), W, H, 90.0, 0.05, 10.0)
    poses = [camera_pose([0.0, 0.0, 1.2], 0.5, 25.0), camera_pose([0.1, 0.1, 1.25], 0.8, 20.0)]
    return cam.K, [(*cam.render(T), T) for T in poses]


def _mapper(**kw) -> OnlineMapper:
    cfg = MapperConfig(backend="cpu", init_subsample=0.3, init_scale_by_resolution=False, **kw)
    return OnlineMapper(cfg, near=0.05, far=10.0, seed=0, device="cpu")


def _depth_error(mapper: OnlineMapper, view, K) -> float:
    rgb, depth, T = view
    out = mapper.render_view(T, K, W, H)
    return float(depth_l1(out.depth[0], torch.from_numpy(depth)[..., None]))


def test_optimization_reduces_the_loss_and_fits_observed_depth(views):
    K, vs = views
    frozen = _mapper(k_new=0, k_replay=0)
    frozen.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    trained = _mapper(k_new=40, k_replay=0)
    stats = trained.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    assert stats.added == len(frozen.map) > 0  # same seed, same initialization
    before, after = frozen.frame_loss(0), trained.frame_loss(0)
    assert after < 0.8 * before
    d_before, d_after = _depth_error(frozen, vs[0], K), _depth_error(trained, vs[0], K)
    assert d_after < 0.8 * d_before  # mostly by closing the holes between the initial splats
    # the optimizer state moved with the splats it updated
    assert int(trained.map["adam_step"].max()) == 40
    assert int(trained.map["n_observed"].max()) == 1


def test_second_frame_adds_only_unseen_surface_and_replays(views):
    K, vs = views
    mapper = _mapper(k_new=4, k_replay=3)
    first = mapper.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    second = mapper.add_frame(vs[1][0], vs[1][1], K, vs[1][2])
    assert 0 < second.added < first.added
    assert second.total == first.added + second.added == len(mapper.map)
    created = mapper.map["frame_created"]
    assert int((created == 1).sum()) == second.added
    assert len(mapper.frames) == 2 and mapper.frames[0].depth_mm.dtype == torch.int16
    # splats of the first frame were trained by replay as well (K_replay steps on frame 0)
    assert int(mapper.map["adam_step"][created == 0].max()) > 4
    # optimization calls: frame 0's K_new (1), its 3 self-replays (2-4), frame 1's K_new (5), 3 replays of 0
    assert mapper.last_trained == [8, 5]


def test_refine_replays_every_stored_frame_and_lowers_their_loss(views):
    K, vs = views
    mapper = _mapper(k_new=3, k_replay=1, replay="stale", prune_opacity=0.05)
    for rgb, depth, T in vs:
        mapper.add_frame(rgb, depth, K, T)
    before = [mapper.frame_loss(i) for i in range(2)]
    clock = mapper._clock
    mapper.refine(30)
    assert mapper._clock == clock + 30 and min(mapper.last_trained) > clock  # both frames drawn
    after = [mapper.frame_loss(i) for i in range(2)]
    assert all(a < 0.9 * b for a, b in zip(after, before))
    assert len(mapper.frames) == 2  # no frame added
    assert bool((torch.sigmoid(mapper.map["opacity_logits"]) >= 0.05).all())  # pruned as after a frame
    with pytest.raises(ValueError, match="iterations"):
        mapper.refine(-1)


def test_stale_replay_draws_frames_in_proportion_to_the_calls_since_their_training():
    mapper = _mapper(replay="stale")
    mapper.last_trained, mapper._clock = [1, 2, 50, 51], 51  # frame 3 is the one being added
    picks = np.bincount([mapper._replay_pick(3) for _ in range(4000)], minlength=4)
    expected = np.array([51, 50, 2, 0]) / 103  # weights 1 + 51 - last_trained over the earlier frames
    assert np.abs(picks / 4000 - expected).max() < 0.03
    assert picks[3] == 0


def test_pruning_drops_transparent_splats_with_their_state(views):
    K, vs = views
    mapper = _mapper(k_new=5, k_replay=0, prune_opacity=0.69)
    mapper.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    opacity = torch.sigmoid(mapper.map["opacity_logits"])
    assert torch.all(opacity >= 0.69)
    assert mapper.map["adam_m.means"].shape[0] == len(mapper.map)


def test_pruning_keeps_every_column_of_the_kept_splats_in_step(views):
    """Each kept splat's row moves whole: parameters, moments, reliability, bookkeeping and a column a
    selector registered, identified through a tag column written before the prune."""
    K, vs = views
    mapper = _mapper(k_new=6, k_replay=0)
    mapper.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    g = mapper.map
    g.add_column("tag", (), torch.int64)
    g["tag"][:] = torch.arange(len(g))
    g.add_column("reliability", (2,), torch.float32)
    g["reliability"][:] = torch.randn(len(g), 2, generator=torch.Generator().manual_seed(0))
    before = {name: g[name].clone() for name in g._cols}
    opacity = torch.sigmoid(g["opacity_logits"])
    threshold = float(torch.quantile(opacity, 0.3))
    mapper.cfg = dataclasses.replace(mapper.cfg, prune_opacity=threshold)
    mapper._prune()
    kept = before["tag"][opacity >= threshold]
    assert 0 < len(g) < len(before["tag"]) and torch.equal(g["tag"], kept)
    for name, col in before.items():
        assert torch.equal(g[name], col[kept]), name
    assert mapper.pruned == len(before["tag"]) - len(g)


def test_pruned_voxels_are_not_reseeded(views):
    K, vs = views
    mapper = _mapper(k_new=4, k_replay=0)
    rgb, depth, T = vs[0]
    mapper.add_frame(rgb, depth, K, T)
    g = mapper.map
    # make every splat in one half of the frame transparent, then prune them
    side = g["means"][:, 1] > float(g["means"][:, 1].median())
    g["opacity_logits"][side] = -10.0
    mapper.cfg = dataclasses.replace(mapper.cfg, prune_opacity=0.01)
    mapper._prune()
    assert mapper.tombstones.size > 0 and len(g) == int((~side).sum())
    forgetful = copy.deepcopy(mapper)
    forgetful.tombstones = np.zeros(0, np.int64)

    def seeded_in_tombstones(m: OnlineMapper) -> int:
        m.cfg = dataclasses.replace(m.cfg, k_new=0)  # the new splats stay where they were seeded
        m.add_frame(rgb, depth, K, T)  # the same view again
        new = m.map["means"][m.map["frame_created"] == 1].numpy()
        return int(np.isin(voxel_keys(new, m.cfg.gamma), mapper.tombstones).sum())

    assert seeded_in_tombstones(forgetful) > 100  # without them the pruned half is seeded afresh
    assert seeded_in_tombstones(mapper) == 0


def test_frame_without_valid_depth_is_a_warned_no_op(views, caplog):
    K, vs = views
    mapper = _mapper(k_new=2, k_replay=2)
    rgb, depth, T = vs[0]
    with caplog.at_level(logging.WARNING):
        stats = mapper.add_frame(rgb, np.full_like(depth, np.nan), K, T)
    assert stats.added == 0 and len(mapper.map) == 0 and len(mapper.frames) == 0
    assert "no valid depth" in caplog.text
    mapper.add_frame(rgb, depth, K, T)
    assert len(mapper.map) > 0


def test_seed_density_on_the_surface_does_not_depend_on_the_image_size(views):
    _, vs = views
    T = vs[0][2]
    counts = {}
    for w, h in ((W, H), (2 * W, 2 * H)):
        cam = RGBDCamera(build_world(make_scene("office0", 0), load_config(None), with_drone=False), w, h, 90.0,
                         0.05, 10.0)
        rgb, depth = cam.render(T)
        mapper = OnlineMapper(MapperConfig(backend="cpu", init_subsample=0.01, k_new=0, k_replay=0), seed=0)
        counts[w] = mapper.add_frame(rgb, depth, cam.K, T).added
    assert abs(counts[2 * W] / counts[W] - 1.0) < 0.1, counts
    # the option off: the share is per pixel, so four times the pixels seed about four times the splats
    off = MapperConfig(init_subsample=0.01, init_scale_by_resolution=False)
    assert seed_share(off, 2 * W, 2 * H) == seed_share(off, W, H) == 0.01
    assert seed_share(MapperConfig(init_subsample=0.1), 320, 240) == 0.4
    assert seed_share(MapperConfig(init_subsample=0.5), 320, 240) == 1.0


def test_training_the_cameras_splats_equals_training_the_whole_map(views):
    """_optimize trains a gathered copy of the splats that may reach the camera: every column of the
    map (parameters, moments, steps, observation counts) must end bit for bit as a full-map run leaves
    it. Torch computes the last few elements of an elementwise op (e.g. the sigmoid) with its scalar
    formula, which can differ from the vector one in the last bit, so the same splat can round
    differently at another position; the map is cut so the camera's splats are exactly the first
    rows, a multiple of 32 long: then both runs take the vector path for every one of them."""
    K, vs = views
    scene = make_scene("office0", 0)
    cam = RGBDCamera(build_world(scene, load_config(None), with_drone=False), W, H, 90.0, 0.05, 10.0)
    behind = camera_pose([0.0, 0.0, 1.2], 0.5 + np.pi, 25.0)
    subset = _mapper(k_new=3, k_replay=0)
    subset.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    n0 = len(subset.map)
    subset.add_frame(*cam.render(behind), K, behind)
    keep = torch.ones(len(subset.map), dtype=torch.bool)
    keep[n0 // 32 * 32:n0] = False  # the other view's splats stay, behind the camera
    subset.map.keep(keep)
    full = copy.deepcopy(subset)
    frame = subset.frames[0]
    rows = subset._view_rows(frame.viewmat, frame.K, W, H)
    assert torch.equal(rows, torch.arange(n0 // 32 * 32)) and len(rows) < len(subset.map)
    subset._optimize(0, 5, count_observed=True)

    target = full._target(frame)
    leaves = full.adam.leaves()
    for it in range(5):
        out = full._render(leaves, frame.viewmat[None], frame.K[None], W, H, TRAIN_OUTPUTS)
        full._loss(out, target).backward()
        visible = torch.nonzero(out.radii[0] > 0, as_tuple=True)[0]
        if it == 0:
            full.map["n_observed"][visible] += 1
        full.adam.step(leaves, visible)
    for name in subset.map._cols:
        assert torch.equal(subset.map[name], full.map[name]), name
    assert bool((subset.map["adam_step"] > 3).any())  # the 5 iterations did update splats



def test_k_new_stop_ends_a_new_frames_iterations_once_its_loss_has_fallen_enough(views):
    from flightrecon import profiling

    K, vs = views
    rgb, depth, T = vs[0]

    def iterations(**kw) -> int:
        m = _mapper(k_new=30, k_replay=0, **kw)
        with profiling.profiling() as prof:
            m.add_frame(rgb, depth, K, T)
        return prof.calls["render"]

    assert iterations() == 30  # the paper's fixed K_new
    assert iterations(k_new_stop=1.0, k_new_min=4) == 4  # any loss is within 100% of the first
    # a share the loss reaches part way: the iterations end between k_new_min and K_new, at the first
    # iteration whose loss is at most that share of the first (read off a fixed-K run's own losses)
    m = _mapper(k_new=30, k_replay=0)
    losses = []
    original = m._loss
    m._loss = lambda out, target, keep: losses.append(float(original(out, target, keep).detach())) or original(
        out, target, keep)
    m.add_frame(rgb, depth, K, T)
    share = losses[12] / losses[0] + 1e-6
    expected = next(i for i, v in enumerate(losses) if i + 1 >= 5 and v <= share * losses[0]) + 1
    assert 5 <= expected <= 13
    assert iterations(k_new_stop=share, k_new_min=5) == expected


@pytest.mark.parametrize("window", [Window(0, 0, 48, 36), Window(59, 37, 37, 35), Window(13, 7, 1, 1),
                                    Window(0, 0, W, H)])
def test_a_window_renders_as_the_same_crop_of_the_whole_frames_render(views, window):
    """The camera of a window (window_intrinsics) draws exactly its pixels of the whole frame's image:
    corners, odd sizes off the 16-pixel tiles, one pixel and the whole frame."""
    K, vs = views
    mapper = _mapper(k_new=5, k_replay=0)
    mapper.add_frame(*vs[0][:2], K, vs[0][2])
    whole = mapper.render_view(vs[1][2], K, W, H)
    part = mapper.render_view(vs[1][2], window_intrinsics(torch.as_tensor(K, dtype=torch.float32), window).numpy(),
                              window.width, window.height)
    for name in ("features", "alpha", "depth"):
        crop = getattr(whole, name)[0, window.rows, window.cols]
        assert torch.allclose(getattr(part, name)[0], crop, atol=2e-5), name


def test_replay_windows_have_the_configured_size_and_reach_every_corner_of_the_frame(views):
    K, vs = views
    mapper = _mapper(replay_window=0.5)
    mapper.add_frame(*vs[0][:2], K, vs[0][2])
    windows = [mapper._replay_window(mapper.frames[0]) for _ in range(3000)]
    assert {(w.width, w.height) for w in windows} == {(48, 36)}
    x0, y0 = np.array([w.x0 for w in windows]), np.array([w.y0 for w in windows])
    assert x0.min() == 0 and x0.max() == W - 48 and y0.min() == 0 and y0.max() == H - 36
    assert _mapper(replay_window=1.0)._replay_window(mapper.frames[0]) is None  # the paper: the whole frame
    tiny = _mapper(replay_window=0.1)._replay_window(mapper.frames[0])
    assert (tiny.width, tiny.height) == (10, 7)


def test_a_replay_window_updates_only_the_splats_that_reach_it(views):
    K, vs = views
    mapper = _mapper(k_new=5, k_replay=0)
    mapper.add_frame(*vs[0][:2], K, vs[0][2])
    before = {name: mapper.map[name].clone() for name in ("means", "colors", "adam_step")}
    window = Window(0, 0, 30, 24)  # the top-left corner
    frame = mapper.frames[0]
    Kw = window_intrinsics(frame.K, window)
    reach = mapper.render_view(frame.T_wc, Kw.numpy(), window.width, window.height).radii[0] > 0
    mapper._optimize(0, 1, window=window)
    stepped = mapper.map["adam_step"] > before["adam_step"]
    assert 0 < int(stepped.sum()) < len(mapper.map) // 2
    assert torch.equal(stepped, reach)
    for name in ("means", "colors"):
        assert torch.equal(mapper.map[name][~reach], before[name][~reach]), name


def test_downsampled_frames_hold_the_block_means_and_drop_depth_that_straddles_an_edge():
    """Held to loops over the blocks: 2x2 and 3x3 blocks of a 7x10 frame with holes, a depth step and
    a gentle slope (the rows and columns past the last whole block are dropped)."""
    rng = np.random.default_rng(3)
    rgb = rng.random((7, 10, 3)).astype(np.float32)
    depth = (2.0 + 0.01 * np.arange(10, dtype=np.float32))[None].repeat(7, 0)  # 0.5% a pixel: kept
    depth[:, 5:] += 1.0  # a step between columns 4 and 5
    depth[1, 1] = depth[4, 8] = 0.0  # holes
    for f in (2, 3):
        color, mean_depth = downsample(torch.from_numpy(rgb), torch.from_numpy(depth)[..., None], f)
        h, w = 7 // f, 10 // f
        assert color.shape == (h, w, 3) and mean_depth.shape == (h, w, 1)
        for i in range(h):
            for j in range(w):
                block = depth[f * i:f * i + f, f * j:f * j + f]
                agree = block.min() > 0 and block.max() - block.min() <= BLOCK_DEPTH_SPREAD * block.mean()
                assert float(mean_depth[i, j, 0]) == pytest.approx(block.mean() if agree else 0.0, rel=1e-6)
                assert np.allclose(color[i, j].numpy(), rgb[f * i:f * i + f, f * j:f * j + f].mean((0, 1)))
        straddling = [j for j in range(w) if f * j < 5 < f * j + f]
        assert straddling and all(float(mean_depth[i, j, 0]) == 0.0 for i in range(h) for j in straddling)
    same = downsample(torch.from_numpy(rgb), torch.from_numpy(depth)[..., None], 1)
    assert torch.equal(same[0], torch.from_numpy(rgb))
    with pytest.raises(ValueError, match="no whole 8x8 block"):
        downsample(torch.from_numpy(rgb), torch.from_numpy(depth)[..., None], 8)


@pytest.mark.parametrize("factor", [2, 3])
def test_a_downsampled_pixel_sees_along_the_mean_ray_of_its_block(factor):
    """Rays are affine in pixel coordinates, so the ray through a block's center is the mean of its
    pixels' rays: the scaled camera's ray through each pixel must be that mean."""
    K = np.array([[160.3, 0.0, 161.2], [0.0, 158.9, 118.7], [0.0, 0.0, 1.0]])
    full = pixel_rays(12, 9, K)
    small = pixel_rays(12 // factor, 9 // factor, scaled_intrinsics(torch.as_tensor(K), factor).numpy())
    h, w = small.shape[:2]
    means = full[:h * factor, :w * factor].reshape(h, factor, w, factor, 3).mean(axis=(1, 3))
    assert np.allclose(small, means, atol=1e-12)


def test_a_downsampled_replay_trains_the_map_toward_the_full_resolution_frame(views):
    """A map seeded from a frame with a few iterations, then replayed on that frame at half its size:
    its full-resolution loss falls, and only the splats that reach the small image are touched."""
    K, vs = views
    mapper = _mapper(k_new=3, k_replay=0, replay_downsample=2)
    mapper.add_frame(*vs[0][:2], K, vs[0][2])
    frame = mapper.frames[0]
    small_K = scaled_intrinsics(frame.K, 2)
    reach = mapper.render_view(frame.T_wc, small_K.numpy(), W // 2, H // 2).radii[0] > 0
    before = {name: mapper.map[name].clone() for name in ("means", "adam_step")}
    loss_before = mapper.frame_loss(0)
    mapper._optimize(0, 1, factor=2)
    stepped = mapper.map["adam_step"] > before["adam_step"]
    assert torch.equal(stepped, reach)
    assert torch.equal(mapper.map["means"][~reach], before["means"][~reach])
    mapper.refine(30)  # replays frame 0, the only one, at half size
    assert mapper.frame_loss(0) < 0.8 * loss_before


def _in_view(points: np.ndarray, T_wc: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Points in front of the camera that project inside its W x H image."""
    p = (points - T_wc[:3, 3]) @ T_wc[:3, :3]
    z = np.maximum(p[:, 2], 1e-9)
    u, v = K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]
    return (p[:, 2] > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)


def test_seeding_where_unexplained_leaves_the_surface_a_fitted_frame_already_renders(views):
    """A view turned 45 degrees from a fitted one shares half its field. Where the fitted view did not
    look, both rules seed alike (every pixel there is unexplained); in the shared half, seeding where
    unexplained adds at most half of what seeding everywhere adds (the voxels between the first view's
    splats), and only where that map still has gaps or errors."""
    K, vs = views
    scene = make_scene("office0", 0)
    cam = RGBDCamera(build_world(scene, load_config(None), with_drone=False), W, H, 90.0, 0.05, 10.0)
    first = camera_pose([0.0, 0.0, 1.2], 0.5, 10.0)
    turned = camera_pose([0.0, 0.0, 1.2], 0.5 + np.pi / 4, 10.0)
    added = {}
    for where in ("everywhere", "unexplained"):
        mapper = _mapper(k_new=60, k_replay=0, seed_where=where)
        mapper.add_frame(*cam.render(first), K, first)
        n0 = len(mapper.map)
        mapper.add_frame(*cam.render(turned), K, turned)
        added[where] = mapper.map["means"][n0:].numpy().astype(np.float64)
    shared = {where: _in_view(points, first, K) for where, points in added.items()}
    outside = {where: int((~inside).sum()) for where, inside in shared.items()}
    assert abs(outside["unexplained"] - outside["everywhere"]) < 0.15 * outside["everywhere"]
    assert 0 < shared["unexplained"].sum() <= 0.5 * shared["everywhere"].sum()
