"""Online optimization on MuJoCo RGB-D views of a procedural scene, with the C++ rasterizer."""

import logging

import numpy as np
import pytest
import torch

from flightrecon.config import MapperConfig, load_config
from flightrecon.geometry import camera_pose
from flightrecon.mapping.image_metrics import depth_l1
from flightrecon.mapping.mapper import OnlineMapper, seed_share
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


def test_pruning_drops_transparent_splats_with_their_state(views):
    K, vs = views
    mapper = _mapper(k_new=5, k_replay=0, prune_opacity=0.69)
    mapper.add_frame(vs[0][0], vs[0][1], K, vs[0][2])
    opacity = torch.sigmoid(mapper.map["opacity_logits"])
    assert torch.all(opacity >= 0.69)
    assert mapper.map["adam_m.means"].shape[0] == len(mapper.map)


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
