"""What the loop carries between frames, and its part of a checkpoint (the components save their own).

The checkpoint's "mission" entry keeps the keys it has always had, so a run killed before this
module existed resumes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flightrecon.evaluation.coverage import SurfaceCoverage


@dataclass
class MissionState:
    """Everything the loop itself carries between frames (the components carry their own)."""

    frame: int = 0
    records: list = field(default_factory=list)
    events: list = field(default_factory=list)
    visited: list = field(default_factory=list)  # (position, yaw) of every capture
    flight_distance: float = 0.0
    wall_time: float = 0.0
    reliable_ema: float = 0.0  # EMA of the selector's stopping statistic (mission.stopping)
    told_no_room: bool = False  # the user was told the drone cannot leave its take-off point
    dataset_frames: list = field(default_factory=list)  # output.dataset: the transforms.json entries so far
    coverage: SurfaceCoverage | None = None  # output.diagnose: what the captured depth has reached
    diagnosis: list = field(default_factory=list)  # output.diagnose: one row per frame

    def to_checkpoint(self) -> dict:
        """The state as arrays and JSON values (flightrecon.checkpoint)."""
        return {"frame": self.frame, "records": self.records, "events": self.events,
                "visited_positions": np.array([p for p, _ in self.visited], float).reshape(-1, 3),
                "visited_yaws": [y for _, y in self.visited], "flight_distance": self.flight_distance,
                "wall_time": self.wall_time, "reliable_ema": self.reliable_ema, "told_no_room": self.told_no_room,
                "dataset_frames": self.dataset_frames, "diagnosis": self.diagnosis,
                "coverage": self.coverage.get_state() if self.coverage is not None else None}

    @classmethod
    def from_checkpoint(cls, m: dict, coverage: SurfaceCoverage | None) -> "MissionState":
        """The state `to_checkpoint` saved; `coverage` (output.diagnose's, built for this run) gets its saved state."""
        if coverage is not None and m["coverage"] is not None:
            coverage.set_state(m["coverage"])
        return cls(
            frame=m["frame"], records=m["records"], events=m["events"],
            visited=[(np.asarray(p, float), float(y)) for p, y in zip(m["visited_positions"], m["visited_yaws"])],
            flight_distance=m["flight_distance"], wall_time=m["wall_time"], reliable_ema=m["reliable_ema"],
            told_no_room=m["told_no_room"], dataset_frames=m["dataset_frames"], coverage=coverage,
            diagnosis=m["diagnosis"])
