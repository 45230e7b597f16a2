"""How a run starts: the climb from the floor to its take-off point, then the first views turning in place.

The take-off point is chosen and checked against the scene by flightrecon.takeoff (moved off the
default when that is unsafe); this module flies to it. The first `budget.initial_views` frames turn
in place by a full turn's share each, so the map holds a panorama before any selector chooses.
"""

from __future__ import annotations

import math

import numpy as np

from flightrecon.control.trajectory import FlatState
from flightrecon.planning.feasibility import CandidateResult, Planner
from flightrecon.sim.flight import Flight
from flightrecon.takeoff import TakeOff


def climb(flight: Flight, takeoff: TakeOff, hover: np.ndarray) -> None:
    """Rest on the floor below the take-off point, climb to `hover` and settle there."""
    flight.start(takeoff.ground, 0.0)
    flight.go_to(hover, 0.0)
    flight.wait_until_arrived()


def initial_turn(planner: Planner, start: FlatState, frame: int, initial_views: int) -> list[CandidateResult] | None:
    """The one candidate of a first-views frame (the next heading in place, checked by the planner),
    or None once the frame after `frame` is no longer one of the `initial_views` (the selector chooses)."""
    if frame + 1 >= initial_views:
        return None
    step = 2 * math.pi / initial_views
    return planner.check(start, start.position[None], np.array([start.yaw + step]))
