"""No feasible candidate: turn in place, else back-track to an earlier viewpoint, else hover.

A flight never crashes on an empty choice: each way out is checked by the planner like any
candidate, and the one taken is said in events.log. A drone that has not moved and finds no way
out is almost always in a workspace that leaves it no room; `no_room_text` says what to change.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from flightrecon.control.trajectory import FlatState
from flightrecon.planning.feasibility import CandidateResult, Planner

BACKTRACK_VIEWS = 5  # earlier viewpoints tried, most recent first


@dataclass(frozen=True)
class Recovery:
    """The way out taken: `choice` to fly (None: hover), its `kind` for frames.csv and its events.log `text`."""

    choice: CandidateResult | None
    kind: str  # "turn", "backtrack" or "hover"
    text: str
    reasons: dict  # why the candidates failed: planner reason -> count


def recover(planner: Planner, start: FlatState, results: list[CandidateResult], visited: list,
            frame: int) -> Recovery:
    """Turn a quarter or half turn in place; else fly back to one of the last viewpoints (`visited`:
    (position, yaw) of every capture, this one last); else hover."""
    reasons = dict(Counter(r.reason for r in results))
    turns = start.yaw + np.array([math.pi / 2, -math.pi / 2, math.pi])
    for r in planner.check(start, np.repeat(start.position[None], 3, 0), turns):
        if r.feasible:
            return Recovery(r, "turn", f"frame {frame}: no feasible candidate ({reasons}); turning in place", reasons)
    back = visited[-2::-1][:BACKTRACK_VIEWS]
    if back:
        pos = np.array([p for p, _ in back])
        yaws = np.array([y for _, y in back])
        for r in planner.check(start, pos, yaws):
            if r.feasible:
                return Recovery(r, "backtrack", f"frame {frame}: no feasible candidate ({reasons}); back-tracking",
                                reasons)
    return Recovery(None, "hover", f"frame {frame}: no feasible candidate or recovery ({reasons}); hovering", reasons)


def no_room_text(frame: int, start: np.ndarray, workspace: np.ndarray, clearance: float, reasons: dict) -> str:
    """Said once per run when the drone has not moved and nothing around it is feasible: the
    workspace candidates must lie in, and the keys that change it."""
    lo, hi = (np.round(b, 2).tolist() for b in workspace)
    return (f"frame {frame}: the drone cannot leave its take-off point "
            f"{np.round(start, 2).tolist()}: no candidate or recovery is feasible ({reasons}). "
            f"Candidates must lie in the workspace {lo} .. {hi} (the scene's floor to its ceiling, or "
            f"planner.max_height above the floor without one, shrunk by the clearance "
            f"{clearance:.2f} m). Change planner.max_height, "
            "sim.takeoff_height, planner.safety_margin or drone.body_radius, or check scene.up_axis "
            "and scene.unit_scale (`flightrecon scene info` shows the floor, ceiling and workspace)")
