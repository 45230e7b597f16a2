"""The way out when no candidate is feasible, on a real planner: turn in place, else back-track to an
earlier viewpoint, else hover, each said with why the candidates failed."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from flightrecon.control.trajectory import FlatState
from flightrecon.mission import recovery
from flightrecon.planning.feasibility import Planner
from flightrecon.scenario import load_config

HOME = np.array([-2.0, -1.0, 1.2])  # inside the workspace
OUTSIDE = np.array([-1.0, -1.0, 1.2])  # free space beyond the workspace's x limit: nothing there is feasible


@pytest.fixture(scope="module")
def planner() -> Planner:
    room = trimesh.creation.box(extents=[6.0, 5.0, 3.0])
    room.apply_translation([0.0, 0.0, 1.5])
    room.invert()
    cfg = load_config(None, ["planner.use_ground_truth=true"])
    return Planner(cfg, np.array([[-3.0, -2.5, 0.0], [-1.5, 2.5, 3.0]]), room, start_position=HOME)


def _at(position: np.ndarray) -> FlatState:
    return FlatState(position.copy(), np.zeros(3), np.zeros(3), 0.0, 0.0)


def test_a_drone_that_can_turn_turns_in_place(planner):
    way = recovery.recover(planner, _at(HOME), [], [(HOME, 0.0)], 3)
    assert way.kind == "turn" and way.text == "frame 3: no feasible candidate ({}); turning in place"
    np.testing.assert_allclose(way.choice.position, HOME)
    assert abs(abs(way.choice.yaw) - np.pi / 2) < 1e-9  # a quarter turn first


def test_a_drone_that_cannot_turn_flies_back_to_an_earlier_view(planner):
    start = _at(OUTSIDE)
    failed = planner.check(start, np.array([[-1.0, 0.0, 1.2]]), np.array([0.5]))
    visited = [(HOME, 0.3), (OUTSIDE.copy(), 0.0)]  # this capture last: the one before it is tried
    way = recovery.recover(planner, start, failed, visited, 7)
    assert way.kind == "backtrack" and way.reasons == {"out_of_bounds": 1}
    assert way.text == "frame 7: no feasible candidate ({'out_of_bounds': 1}); back-tracking"
    np.testing.assert_allclose(way.choice.position, HOME)
    assert way.choice.yaw == pytest.approx(0.3)


def test_a_drone_with_no_way_out_hovers(planner):
    way = recovery.recover(planner, _at(OUTSIDE), [], [(OUTSIDE.copy(), 0.0)], 7)
    assert way.kind == "hover" and way.choice is None
    assert way.text == "frame 7: no feasible candidate or recovery ({}); hovering"
    text = recovery.no_room_text(7, OUTSIDE, planner.workspace, 0.35, way.reasons)
    assert "cannot leave its take-off point [-1.0, -1.0, 1.2]" in text and "planner.max_height" in text
