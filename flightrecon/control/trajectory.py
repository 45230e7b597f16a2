"""The trajectory interface between the planner and the controller.

A trajectory is any object with a `duration` and `sample(t)`; times past the end return the final
state at rest. The planner (ruckig segments) produces them; the flight cycle consumes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class FlatState:
    """Flat outputs of a quadrotor at one instant (world frame)."""

    position: np.ndarray  # (3,)
    velocity: np.ndarray  # (3,)
    acceleration: np.ndarray  # (3,)
    yaw: float
    yaw_rate: float = 0.0


@runtime_checkable
class Trajectory(Protocol):
    @property
    def duration(self) -> float: ...

    def sample(self, t: float) -> FlatState: ...


@dataclass(frozen=True)
class Hold:
    """Stay at one position and heading (hover, take-off target, recovery)."""

    position: np.ndarray
    yaw: float
    duration: float = 0.0

    def sample(self, t: float) -> FlatState:
        z = np.zeros(3)
        return FlatState(np.asarray(self.position, float), z, z, float(self.yaw), 0.0)
