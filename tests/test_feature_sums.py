"""Sided feature sums (the C++ kernel behind 2D GauSS-MI scoring) against their torch twin, the
cut's bound, and culled scoring against exact scoring on maps from a real flight."""

import math

import numpy as np
import pytest
import torch

from flightrecon.active import gaussmi2d
from flightrecon.active.protocol import scoring_intrinsics
from flightrecon.control.trajectory import FlatState
from flightrecon.errors import DataError, FlightReconError
from flightrecon.geometry import camera_pose, intrinsics, rotmat_to_quat
from flightrecon.mission import Mission
from flightrecon.render import render, sided_feature_sums
from flightrecon.render.feature_sums import side_values, view_cosines
from flightrecon.render.extension import load
from flightrecon.render.projection import quat_to_rotmat
from flightrecon.scenario import load_config

W, H = 48, 36


def _cloud(n: int = 400, seed: int = 0) -> list[torch.Tensor]:
    """Splats in a box in front of the cameras, random orientations (both sides get seen)."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * torch.tensor([2.0, 2.0, 1.5]) + torch.tensor([1.5, -1.0, 0.5])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.log(torch.rand(n, 2, generator=g) * 0.08 + 0.02)
    opac = torch.randn(n, generator=g) + 1.0
    return [means, quats, log_scales, opac]


def _cams(count: int = 5, seed: int = 1):
    rng = np.random.default_rng(seed)
    poses = [camera_pose(np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.2]), rng.uniform(-0.4, 0.4))
             for _ in range(count)]
    T = torch.tensor(np.stack(poses), dtype=torch.float32)
    K = torch.tensor(intrinsics(W, H, 90.0), dtype=torch.float32).repeat(count, 1, 1)
    return torch.linalg.inv(T), K


def _twin(splats, sided, viewmats, Ks, w_min, weighted):
    """The torch statement: per-camera features from the cosines, rendered, summed in float64."""
    normals = quat_to_rotmat(torch.nn.functional.normalize(splats[1], dim=-1))[..., 2]
    centers = torch.linalg.inv(viewmats)[:, :3, 3]
    f = side_values(view_cosines(splats[0], normals, centers), sided, w_min, weighted)[..., None]
    out = render(*splats, f, viewmats, Ks, W, H, outputs=("features",), backend="reference")
    return out.features[..., 0].double().sum(dim=(1, 2))


@pytest.mark.parametrize("weighted", [True, False])
def test_kernel_equals_torch_twin(weighted):
    splats = _cloud()
    sided = torch.rand(len(splats[0]), 2, generator=torch.Generator().manual_seed(3)) * 2.0
    vm, K = _cams()
    got = sided_feature_sums(*splats, sided, vm, K, W, H, w_min=0.1, weighted=weighted, backend="cpu")
    want = _twin(splats, sided, vm, K, 0.1, weighted)
    assert (want > 0).all()
    torch.testing.assert_close(got.sums, want, rtol=2e-5, atol=1e-6)
    assert (got.bound == 0).all()


def test_back_side_and_edge_on_pick_their_values():
    # one splat facing -x at x = 2; a camera in front sees its front value, behind it its back value
    means = torch.tensor([[2.0, 0.0, 1.2]])
    R = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns t_u, t_v, n
    quats = torch.tensor(rotmat_to_quat(R)[None], dtype=torch.float32)
    splats = [means, quats, torch.full((1, 2), math.log(0.2)), torch.tensor([3.0])]
    sided = torch.tensor([[1.0, 7.0]])
    T = torch.tensor(np.stack([camera_pose(np.array([0.0, 0.0, 1.2]), 0.0),
                               camera_pose(np.array([4.0, 0.0, 1.2]), math.pi)]), dtype=torch.float32)
    K = torch.tensor(intrinsics(W, H, 90.0), dtype=torch.float32).repeat(2, 1, 1)
    s = sided_feature_sums(*splats, sided, torch.linalg.inv(T), K, W, H, w_min=0.1, backend="cpu").sums
    alpha = render(*splats, torch.ones(1, 1), torch.linalg.inv(T), K, W, H, outputs=("alpha",), backend="cpu").alpha
    coverage = alpha[..., 0].double().sum(dim=(1, 2))
    torch.testing.assert_close(s, torch.tensor([1.0, 7.0], dtype=torch.float64) * coverage, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])  # the AVX2 loop and the generic one
@pytest.mark.parametrize("floor", [1e-3, 0.05, 0.5])
def test_cut_stays_within_its_bound(floor, dtype):
    splats = [t.to(dtype) for t in _cloud(600, seed=4)]
    g = torch.Generator().manual_seed(5)
    sided = torch.where(torch.rand(600, 2, generator=g) < 0.7, 1e-4, torch.rand(600, 2, generator=g)).to(dtype)
    vm, K = _cams(6, seed=6)
    exact = sided_feature_sums(*splats, sided, vm, K, W, H, w_min=0.1, backend="cpu").sums
    cut = sided_feature_sums(*splats, sided, vm, K, W, H, w_min=0.1, floor=floor, backend="cpu")
    slack = 1e-5 * exact.abs() + 1e-9
    assert (cut.sums <= exact + slack).all()
    assert (exact <= cut.sums + cut.bound + slack).all()
    assert (cut.bound <= floor * W * H).all()


def test_zero_features_stop_every_pixel_at_no_cost_to_the_bound():
    splats = _cloud(600, seed=4)
    vm, K = _cams(6, seed=6)
    cut = sided_feature_sums(*splats, torch.zeros(600, 2), vm, K, W, H, w_min=0.1, floor=1e-3, backend="cpu")
    assert (cut.sums == 0).all() and (cut.bound == 0).all()
    assert load().last_stats()["evals"] == 0  # nothing left to add: no pixel evaluates a splat


@pytest.mark.parametrize("value", [0.0, 1e-40, 1e30])
def test_edge_values_give_finite_sums(value):
    splats = _cloud(200, seed=7)
    sided = torch.full((200, 2), value)
    vm, K = _cams(3)
    out = sided_feature_sums(*splats, sided, vm, K, W, H, w_min=0.1, floor=1e-3, backend="cpu")
    assert torch.isfinite(out.sums).all() and torch.isfinite(out.bound).all()
    if value == 0.0:
        assert (out.sums == 0).all()
    if value == 1e30:
        twin = _twin(splats, sided, vm, K, 0.1, True)
        torch.testing.assert_close(out.sums, twin, rtol=2e-5, atol=0.0)


def test_bad_inputs_name_the_tensor():
    splats = _cloud(50)
    vm, K = _cams(2)
    sided = torch.ones(50, 2)
    sided[3, 1] = float("nan")
    with pytest.raises(DataError, match="sided"):
        sided_feature_sums(*splats, sided, vm, K, W, H, w_min=0.1, backend="cpu")
    with pytest.raises(FlightReconError, match="sided"):
        sided_feature_sums(*splats, torch.ones(50, 3), vm, K, W, H, w_min=0.1, backend="cpu")
    with pytest.raises(FlightReconError, match="floor"):
        sided_feature_sums(*splats, torch.ones(50, 2), vm, K, W, H, w_min=0.1, floor=-1.0, backend="cpu")
    with pytest.raises(FlightReconError, match="negative values: give floor=0"):
        sided_feature_sums(*splats, -torch.ones(50, 2), vm, K, W, H, w_min=0.1, floor=1e-3, backend="cpu")


# ------------------------------------------------------------------ culled scoring on real maps
@pytest.fixture(scope="module")
def flown():
    """A short real flight at the demo's resolution: its map, reliability and the candidate library."""
    cfg = load_config("demo", ["budget.frames=5", "budget.initial_views=2", "mapper.k_new=10",
                               "mapper.k_replay=4", "evaluation.views=2", "evaluation.every=0",
                               "output.record=false", "output.checkpoint=false"])
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        mission = Mission(cfg, tmp, progress=False)
        mission.run()
        s = mission.flight.state
        start = FlatState(s.position, np.zeros(3), np.zeros(3), float(s.yaw), 0.0)
        results = mission.planner.check(start, *mission.planner.library.poses(s.position, s.yaw))
        poses = torch.as_tensor(mission.candidate_poses(results), dtype=torch.float32)
        return mission, poses


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["flown", "all_reliable", "none_reliable", "mixed"])
def test_culled_scoring_picks_the_exact_argmax(flown, kind):
    mission, poses = flown
    splats = mission.mapper.splats()
    rel = mission.selector.reliability(mission.view).clone()
    N = rel.shape[0]
    g = torch.Generator().manual_seed(11)
    if kind == "all_reliable":
        rel[:] = 10.0
    elif kind == "none_reliable":
        rel[:] = torch.rand(N, 2, generator=g) * 2 - 1
    elif kind == "mixed":
        rel = torch.where(torch.rand(N, 2, generator=g) < 0.8, torch.tensor(10.0), rel)
    c = mission.cfg
    K = scoring_intrinsics(c)
    args = dict(w_min=c.reliability.w_min, near=mission.mapper.near, far=mission.mapper.far, backend="cpu")
    w, h = c.selector.scoring_width, c.selector.scoring_height
    exact = gaussmi2d.score_candidates(splats, rel, poses, K, w, h, **args)
    culled = gaussmi2d.score_candidates(splats, rel, poses, K, w, h, gain_floor=1e-3, **args)
    assert len(poses) > 20 and (exact >= 0).all() and float(exact.max()) > 0
    best = int(torch.argmax(exact))
    assert int(torch.argmax(culled)) == best
    assert float(culled[best]) == pytest.approx(float(exact[best]), rel=1e-6)
    assert (culled <= exact * (1 + 1e-5)).all()  # the others keep a lower bound
    # the first pass alone, against exact: inside its bound
    first = sided_feature_sums(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"],
                               torch.nn.functional.softplus(-rel), torch.linalg.inv(poses),
                               K[None].expand(len(poses), 3, 3).contiguous(), w, h, args["near"], args["far"],
                               w_min=args["w_min"], floor=1e-3, backend="cpu")
    assert (exact <= first.sums + first.bound + 1e-5 * exact).all()
    assert (exact - first.sums <= 1e-3 * w * h + 1e-5 * exact).all()  # at most the floor per pixel


@pytest.mark.slow
def test_the_cut_evaluates_fewer_splats_on_a_flown_map(flown):
    mission, poses = flown
    splats = mission.mapper.splats()
    sided = torch.nn.functional.softplus(-mission.selector.reliability(mission.view))
    c = mission.cfg
    K = scoring_intrinsics(c)[None].expand(len(poses), 3, 3).contiguous()
    evals = []
    for floor in (0.0, 1e-3):
        sided_feature_sums(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"], sided,
                           torch.linalg.inv(poses), K, c.selector.scoring_width, c.selector.scoring_height,
                           mission.mapper.near, mission.mapper.far, w_min=c.reliability.w_min, floor=floor,
                           backend="cpu")
        evals.append(load().last_stats()["evals"])
    assert 0 < evals[1] < evals[0]


@pytest.mark.slow
def test_kernel_scoring_equals_torch_statement_on_flown_map(flown):
    mission, poses = flown
    splats = mission.mapper.splats()
    rel = mission.selector.reliability(mission.view)
    c = mission.cfg
    K = scoring_intrinsics(c)
    w, h = c.selector.scoring_width, c.selector.scoring_height
    got = gaussmi2d.score_candidates(splats, rel, poses, K, w, h, w_min=0.1, near=mission.mapper.near,
                                     far=mission.mapper.far, backend="cpu")
    normals = gaussmi2d.splat_normals(splats["quats"])
    gain = gaussmi2d.information_gain(rel, gaussmi2d.observation_weights(splats["means"], normals, poses[:, :3, 3]),
                                      0.1)
    out = render(splats["means"], splats["quats"], splats["log_scales"], splats["opacity_logits"], gain[..., None],
                 torch.linalg.inv(poses), K[None].expand(len(poses), 3, 3).contiguous(), w, h,
                 near=mission.mapper.near, far=mission.mapper.far, outputs=("features",), backend="cpu")
    torch.testing.assert_close(got, out.features[..., 0].double().sum(dim=(1, 2)), rtol=1e-4, atol=1e-6)
