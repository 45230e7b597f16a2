"""gaussmi2d_frontier: ActiveGS's exploration term and the paper's MI combined in ActiveGS's form,
its own weights, and its place in the loop.

The two terms are each held to brute force elsewhere (test_baselines: the exploration voxels; test_active_scoring:
Eq. 22); here a separate ActiveGS and 2D GauSS-MI selector, shown the same frames, give the terms, and
the combination is worked by hand: U = w E + MI / max MI, score U / sum U - p L / sum L.
"""

import math

import numpy as np
import pytest
import torch

from flightrecon.active.baselines import ActiveGSSelector
from flightrecon.active.frontier_mi import GaussMI2DFrontier
from flightrecon.active.protocol import MapView
from flightrecon.active.registry import make_selector
from flightrecon.active.selectors import GaussMI2D
from flightrecon.geometry import camera_pose
from flightrecon.mission import Mission
from flightrecon.scenario import load_config
from test_baselines import TINY, _mapper, _obs

BOUNDS = np.array([[-1.0, -2.0, 0.0], [3.0, 2.0, 2.4]])
CANDIDATES = np.stack([camera_pose(np.array([0.0, 0.1, 1.2]), 0.0),  # the frame already taken
                       camera_pose(np.array([0.3, 0.5, 1.3]), -0.3),  # the wall, from aside
                       camera_pose(np.array([0.0, 0.1, 1.2]), math.pi),  # away from it: unexplored space
                       camera_pose(np.array([0.5, -0.6, 1.1]), 0.4)])
LENGTHS = np.array([0.0, 0.6, 0.0, 0.9])


def _fed(cls, cfg, m):
    sel = cls(cfg)
    sel.attach_scene(BOUNDS)
    sel.observe(MapView(m, sel.columns), _obs(cfg, m, CANDIDATES[0]))
    return sel


@pytest.mark.parametrize("weights", [(1000.0, 0.5), (3.0, 0.0), (0.0, 2.0)])
def test_frontier_mi_combines_activegs_exploration_and_the_papers_mi_by_hand(weights):
    w, p = weights
    cfg = load_config("demo", TINY + ["selector.method=gaussmi2d_frontier", f"frontier_mi.explore_weight={w}",
                                      f"frontier_mi.path_weight={p}"])
    m = _mapper(cfg)
    sel = make_selector(cfg)
    assert isinstance(sel, GaussMI2DFrontier)
    sel.attach_scene(BOUNDS)
    sel.observe(MapView(m, sel.columns), _obs(cfg, m, CANDIDATES[0]))

    ags = _fed(ActiveGSSelector, cfg, _mapper(cfg))
    explore, _ = ags.explore_exploit(MapView(_mapper(cfg), ags.columns), CANDIDATES)
    gm = _fed(GaussMI2D, cfg, _mapper(cfg))
    mi = gm.mutual_information(MapView(_mapper(cfg), gm.columns), CANDIDATES).numpy()
    assert explore[2] > 0 == explore[0] and mi.max() > 0  # both terms present, not the same ordering
    U = [w * e + v / max(mi) for e, v in zip(explore, mi)]
    expect = [u / sum(U) - p * L / sum(LENGTHS) for u, L in zip(U, LENGTHS)]
    np.testing.assert_allclose(sel.score(MapView(m, sel.columns), CANDIDATES, LENGTHS), expect, rtol=1e-6,
                               atol=1e-9)  # float32 MI
    # its settings are its own: ActiveGS's section does not move it
    other = load_config("demo", TINY + ["selector.method=gaussmi2d_frontier", f"frontier_mi.explore_weight={w}",
                                        f"frontier_mi.path_weight={p}", "activegs.explore_weight=7",
                                        "activegs.path_weight=9"])
    twin = _fed(GaussMI2DFrontier, other, _mapper(other))
    np.testing.assert_allclose(twin.score(MapView(_mapper(other), twin.columns), CANDIDATES, LENGTHS), expect,
                               rtol=1e-6, atol=1e-9)


def test_frontier_mi_on_an_empty_map_scores_by_exploration_alone():
    cfg = load_config("demo", TINY + ["selector.method=gaussmi2d_frontier"])
    full = _mapper(cfg)
    sel = _fed(GaussMI2DFrontier, cfg, full)
    empty = _mapper(cfg)
    empty.map.keep(torch.zeros(len(empty.map), dtype=torch.bool))
    assert len(empty.map) == 0
    util = sel.utilities(MapView(empty, sel.columns), CANDIDATES)
    assert np.all(np.isfinite(util)) and util.max() > 0


def test_frontier_mi_state_restores_its_scores():
    """A checkpoint carries its voxel map and ActiveGS's random state (ties of all-zero utility)."""
    cfg = load_config("demo", TINY + ["selector.method=gaussmi2d_frontier"])
    m = _mapper(cfg)
    sel = _fed(GaussMI2DFrontier, cfg, m)
    twin = GaussMI2DFrontier(cfg)
    twin.set_state(sel.get_state())
    view = MapView(m, sel.columns)
    np.testing.assert_array_equal(twin.score(view, CANDIDATES, LENGTHS), sel.score(view, CANDIDATES, LENGTHS))


def test_frontier_mi_flies_a_closed_loop(tmp_path):
    over = TINY + ["selector.method=gaussmi2d_frontier", "budget.frames=4", "budget.initial_views=1",
                   "evaluation.every=0", "output.record=false"]
    metrics = Mission(load_config("demo", over), tmp_path, progress=False).run()
    assert metrics["method"] == "gaussmi2d_frontier" and metrics["frames"] == 4
    assert np.isfinite(metrics["eval"]["psnr"])
