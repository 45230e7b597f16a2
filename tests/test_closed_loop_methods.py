"""Every selector flown in a short closed loop (real MuJoCo, OMPL, ruckig, the C++ rasterizer): its
chosen scores stay inside their analytic bounds, its map grows like the others', and the flight
keeps the planner's margin from the true surface.

Bounds: blend weights at a pixel sum to at most 1, so a view scores at most (pixels) x (the largest
per-splat gain). GauSS-MI's gain is sum_k c_k (-ln P_k) <= sqrt(2) (-ln P_min) (c_x + c_y <= sqrt 2);
while its reliabilities stay >= 0.5 that is sqrt(2) ln 2 per pixel, the bound its broken port
exceeded 3-10x. 2D GauSS-MI's gain is |w| (-ln P) <= -ln P of the side seen. ActiveGS's score is
U / sum U - 0.5 L / sum L, in [-0.5, 1]; random's in [0, 1); FisherRF's a sum of ratios of
non-negative Hessians.
"""

import csv
import math

import numpy as np
import pytest

from flightrecon.mission import Mission
from flightrecon.scenario import load_config

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=8", "mapper.k_replay=4", "evaluation.views=3", "evaluation.every=0", "budget.frames=9",
        "budget.initial_views=3", "output.record=false", "output.checkpoint=false"]
METHODS = ("gaussmi2d", "gaussmi", "fisherrf", "activegs", "activegs_native", "random")
NPIX = 40 * 30
MARGIN_SLACK = 0.03  # m: what tracking and the occupancy map (5 cm voxels) may eat of the 10 cm margin


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    out = {}
    for method in METHODS:
        run = tmp_path_factory.mktemp(method)
        mission = Mission(load_config("demo", TINY + [f"selector.method={method}"]), run, progress=False)
        metrics = mission.run()
        with open(run / "frames.csv") as f:
            rows = list(csv.DictReader(f))
        out[method] = (mission, metrics, rows)
    return out


def _chosen(rows) -> np.ndarray:
    v = np.array([float(r["chosen_score"]) for r in rows if r["chosen_score"] not in ("", "nan")])
    return v[np.isfinite(v)]


@pytest.mark.slow
def test_chosen_scores_stay_inside_their_analytic_bounds(flights):
    for method, (mission, _, rows) in flights.items():
        chosen = _chosen(rows)
        assert len(chosen) >= 4, method  # the steps after the initial turns chose among candidates
        if method == "gaussmi":
            l = mission.mapper.map["gaussmi_logodds"]
            assert float((l < 0).float().mean()) < 0.02  # a map that fits its frames is not unreliable
            assert chosen.max() <= NPIX * math.sqrt(2) * math.log(2) * 1.02
        elif method == "gaussmi2d":
            rel = mission.selector.reliability(mission.view)
            worst = float(-np.log(1 / (1 + np.exp(-rel.double().numpy().min()))))
            assert chosen.max() <= NPIX * worst
        elif method.startswith("activegs"):
            assert chosen.min() >= -0.5 and chosen.max() <= 1.0
        elif method == "random":
            assert chosen.min() >= 0 and chosen.max() < 1
        else:
            assert chosen.min() >= 0 and np.isfinite(chosen).all()


@pytest.mark.slow
def test_every_map_grows_like_the_others(flights):
    splats = {m: metrics["splats"] for m, (_, metrics, _) in flights.items()}
    median = float(np.median(list(splats.values())))
    assert all(n > 0.6 * median for n in splats.values()), splats
    moved = {m: metrics["flight_distance_m"] for m, (_, metrics, _) in flights.items()}
    assert all(d > 0.3 for d in moved.values()), moved


@pytest.mark.slow
def test_flights_keep_the_planners_margin_from_the_true_surface(flights):
    """min_clearance is the exact distance from the body sphere to the scene's triangles."""
    for method, (mission, metrics, rows) in flights.items():
        margin = mission.cfg.planner.safety_margin
        clear = np.array([float(r["min_clearance"]) for r in rows if r["min_clearance"] not in ("", "nan")])
        assert metrics["contacts"] == 0, method
        assert clear.min() >= margin - MARGIN_SLACK, (method, clear.min())
