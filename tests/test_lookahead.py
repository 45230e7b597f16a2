"""gaussmi2d_lookahead: sequences of views valued per second, their items, travel times, and the loop."""

import math

import numpy as np
import pytest
import torch

from flightrecon.active.lookahead import GaussMI2DLookahead, camera_yaw, leg_time, sequence_rates
from flightrecon.active.registry import make_selector
from flightrecon.geometry import camera_pose
from flightrecon.mission import Mission
from flightrecon.planning.timing import Limits
from flightrecon.scenario import load_config
from test_explore import TINY, _half_known_room

LOOKAHEAD = [*TINY, "selector.method=gaussmi2d_lookahead"]


def test_a_view_that_opens_a_better_second_view_wins_over_the_greedy_choice():
    # items: A alone 2.4; B 2 and C 2.5 on separate items; D repeats B's item. One view: C is best
    # (2.5 / (1 + 1) = 1.25 per s), but B then C (0.5 s apart) gains 4.5 in 1 + 1 + 0.5 + 1 = 3.5 s.
    items = np.array([[2.4, 0, 0], [0, 2, 0], [0, 0, 2.5], [0, 2, 0]])
    first = np.ones(4)
    between = np.full((4, 4), 4.0)
    between[1, 2] = 0.5
    between[1, 3] = between[3, 1] = 0.0
    one, _ = sequence_rates(items, first, between, view_time=1.0, depth=1)
    np.testing.assert_allclose(one, [1.2, 1.0, 1.25, 1.0])
    two, plans = sequence_rates(items, first, between, view_time=1.0, depth=2)
    np.testing.assert_allclose(two, [max(1.2, 4.9 / 7), 4.5 / 3.5, 1.25, max(1.0, 4.5 / 7)])
    assert plans[1] == (1, 2) and plans[0] == (0,)
    # B then D sees B's item twice: it gains 2 once, so the pair is worth less per second than B alone
    assert plans[3] != (3, 1)
    three, plans = sequence_rates(items, first, between, view_time=1.0, depth=3)
    assert three[1] == pytest.approx(max(4.5 / 3.5, (2 + 2.5 + 2.4) / (3 + 1 + 0.5 + 4)))
    assert all(three >= two - 1e-12)  # a longer horizon only adds sequences


def test_a_single_candidate_and_zero_information():
    rates, plans = sequence_rates(np.array([[1.0, 2.0]]), np.array([2.0]), np.zeros((1, 1)), view_time=1.0, depth=3)
    assert rates[0] == pytest.approx(1.0) and plans == [(0,)]
    rates, _ = sequence_rates(np.zeros((2, 0)), np.ones(2), np.zeros((2, 2)), view_time=1.0, depth=2)
    np.testing.assert_array_equal(rates, [0.0, 0.0])


def test_leg_time_approaches_the_trapezoid_profile_when_jerk_is_unlimited():
    lim = Limits(vel=1.0, acc=2.0, jerk=1e5, yaw_rate=1.0, yaw_acc=1e3, yaw_jerk=1e6)
    assert leg_time(3.0, 0.0, lim) == pytest.approx(3.0 / 1.0 + 1.0 / 2.0, abs=1e-3)  # d/v + v/a
    assert leg_time(0.5, 0.0, lim) == pytest.approx(2 * math.sqrt(0.5 / 2.0), abs=1e-3)  # never at v: 2 sqrt(d/a)
    assert leg_time(0.0, math.pi / 2, lim) == pytest.approx(math.pi / 2 + 1e-3, abs=2e-3)  # the turn alone
    assert leg_time(0.0, 0.0, lim) == pytest.approx(0.0, abs=1e-9)
    slow_jerk = Limits(vel=1.0, acc=2.0, jerk=1.0, yaw_rate=1.0, yaw_acc=1e3, yaw_jerk=1e6)
    assert leg_time(3.0, 0.0, slow_jerk) > leg_time(3.0, 0.0, lim)


@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.5, math.pi - 1e-6])
def test_camera_yaw_reads_the_heading_of_a_camera_pose(yaw):
    assert camera_yaw(camera_pose(np.array([1.0, 2.0, 1.0]), yaw)) == pytest.approx(yaw, abs=1e-9)


def test_unknown_cells_seen_from_two_near_cameras_count_once():
    cfg = load_config("demo", LOOKAHEAD)
    sel = make_selector(cfg)
    assert isinstance(sel, GaussMI2DLookahead)
    sel.occupancy = _half_known_room()  # nothing seen beyond x = 2 where y < 0
    poses = np.stack([camera_pose(np.array([1.0, -1.0, 1.05]), 0.0), camera_pose(np.array([1.0, -1.1, 1.05]), 0.0),
                      camera_pose(np.array([1.0, 2.0, 1.05]), 0.0)])
    items = sel.frontier_items(sel.frontier_entries(poses))
    np.testing.assert_allclose(items.sum(axis=1), sel.frontier_gain(poses))  # binning keeps every ray's gain
    assert items[0].sum() > 0 and items[2].sum() == 0  # facing the wall: only the band before it
    union = np.maximum(items[0], items[1]).sum()
    assert union < 1.3 * max(items[0].sum(), items[1].sum())  # the second camera sees mostly the same cells


def test_the_loop_flies_and_splat_items_sum_to_the_papers_mi(tmp_path):
    mission = Mission(load_config("demo", LOOKAHEAD), tmp_path, progress=False)
    metrics = mission.run()
    assert metrics["method"] == "gaussmi2d_lookahead" and metrics["frames"] == 4
    assert math.isfinite(metrics["eval"]["psnr"])
    sel, view = mission.selector, mission.view
    assert isinstance(sel, GaussMI2DLookahead)
    T = sel.here  # the last captured frame's pose
    poses = np.stack([T, camera_pose(T[:3, 3], math.pi / 2), camera_pose(T[:3, 3] + [0.3, 0, 0], 0.2)])
    items = sel.splat_items(view, poses)
    assert items.shape == (3, len(view)) and bool((items >= 0).all())
    exact = sel.cfg.with_section("reliability", gain_floor=0.0)  # the oracle: the C++ sided sums, uncut
    sel.cfg, culled = exact, sel.cfg
    mi = sel.mutual_information(view, poses).numpy()
    sel.cfg = culled
    np.testing.assert_allclose(items.sum(dim=1).numpy(), mi, rtol=2e-4)
    assert mi.max() > 0
    # one view: the rate of gaussmi2d_explore's score; the state carries where the drone is
    greedy = GaussMI2DLookahead(sel.cfg.with_section("lookahead", depth=1))
    greedy.set_state(sel.get_state())
    np.testing.assert_array_equal(greedy.here, T)
    first = greedy.first_leg_times(poses, None)
    explore = greedy.mutual_information(view, poses, torch.as_tensor(greedy.frontier_gain(poses)))
    got = greedy.score(view, poses)
    assert int(np.argmax(got)) == int(np.argmax(explore.numpy() / (greedy.cfg.lookahead.view_time + first)))


@pytest.mark.parametrize("seed", range(5))
def test_without_travel_no_sequence_beats_its_best_single_view(seed):
    # G(S) <= |S| max_n G({n}) for a union of per-item maxima: per view, a sequence never gains more
    rng = np.random.default_rng(seed)
    items = rng.exponential(size=(6, 40)) * (rng.random((6, 40)) < 0.4)
    rates, plans = sequence_rates(items, rng.random(6), rng.random((6, 6)), view_time=1e9, depth=3)
    best = int(np.argmax(rates))
    assert best == int(np.argmax(items.sum(axis=1)))
    assert rates[best] == pytest.approx(items.sum(axis=1).max() / (1e9 + 1.0), rel=1e-8)
