"""Analytic reference trajectories (Trajectory protocol): min-jerk moves and a figure-eight.

They serve take-off, the scripted survey, controller tests and the flight benchmark, where a
closed-form reference with known derivatives is the oracle. (The planner's ruckig trajectories
implement the same protocol for the active loop.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flightrecon.control.trajectory import FlatState

# Peaks of the min-jerk profile s(u) = 10u^3 - 15u^4 + 6u^5 and its derivatives on u in [0, 1].
_PEAK_VEL, _PEAK_ACC, _PEAK_JERK = 1.875, 10.0 / math.sqrt(3.0), 60.0


def wrap_angle(a: float) -> float:
    """Angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def _smoothstep(u: float) -> tuple[float, float, float]:
    """Min-jerk s(u), s'(u), s''(u) for u clamped to [0, 1]."""
    u = min(max(u, 0.0), 1.0)
    return (u ** 3 * (10 - 15 * u + 6 * u * u), 30 * u * u * (1 - u) ** 2, 60 * u * (1 - u) * (1 - 2 * u))


def min_jerk_duration(distance: float, max_vel: float, max_acc: float, max_jerk: float) -> float:
    """Shortest rest-to-rest min-jerk duration over `distance` that keeps within the three limits."""
    d = abs(distance)
    if d == 0.0:
        return 0.0
    return max(_PEAK_VEL * d / max_vel, math.sqrt(_PEAK_ACC * d / max_acc), (_PEAK_JERK * d / max_jerk) ** (1 / 3))


@dataclass(frozen=True)
class MinJerkMove:
    """Rest-to-rest straight move from p0 to p1, turning from yaw0 to yaw1 the short way."""

    p0: np.ndarray
    p1: np.ndarray
    yaw0: float
    yaw1: float
    duration: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "p0", np.asarray(self.p0, float))
        object.__setattr__(self, "p1", np.asarray(self.p1, float))

    @classmethod
    def within_limits(cls, p0, p1, yaw0: float, yaw1: float, max_vel: float, max_acc: float, max_jerk: float,
                      max_yaw_rate: float, max_yaw_acc: float, min_duration: float = 0.5) -> "MinJerkMove":
        """The fastest such move that respects per-axis and yaw limits (rad/s, rad/s^2)."""
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        axis = float(np.abs(p1 - p0).max())
        dyaw = abs(wrap_angle(yaw1 - yaw0))
        T = max(min_jerk_duration(axis, max_vel, max_acc, max_jerk),
                _PEAK_VEL * dyaw / max_yaw_rate, math.sqrt(_PEAK_ACC * dyaw / max_yaw_acc), min_duration)
        return cls(p0, p1, float(yaw0), float(yaw1), T)

    def sample(self, t: float) -> FlatState:
        T = self.duration
        s, ds, dds = _smoothstep(t / T) if T > 0 else (1.0, 0.0, 0.0)
        delta = self.p1 - self.p0
        dyaw = wrap_angle(self.yaw1 - self.yaw0)
        inv = 1.0 / T if T > 0 else 0.0
        return FlatState(self.p0 + delta * s, delta * ds * inv, delta * dds * inv * inv,
                         wrap_angle(self.yaw0 + dyaw * s), dyaw * ds * inv)


@dataclass(frozen=True)
class FigureEight:
    """Lemniscate of Gerono-like loop p = c + (ax sin phi, ay sin 2phi / 2, 0), yaw fixed.

    The phase rate ramps from rest to 2*pi/period (min-jerk, `ramp` seconds), holds, and ramps down
    to rest, covering exactly `laps` laps (phase 2*pi*laps), so the reference starts and ends hovering
    at `center` for whole laps. Needs laps * period > ramp."""

    center: np.ndarray
    ax: float
    ay: float
    period: float
    laps: float = 1.0
    ramp: float = 2.0
    yaw: float = 0.0

    @property
    def _rate(self) -> float:
        return 2 * math.pi / self.period

    @property
    def duration(self) -> float:
        return self.ramp + self.laps * self.period

    def _phase(self, t: float) -> tuple[float, float, float]:
        """phi, dphi/dt, d2phi/dt2: the ramps integrate the smoothstep (its integral is
        ramp * (2.5u^4 - 3u^5 + u^6)), so each ramp covers rate * ramp / 2 of phase."""
        w, r = self._rate, self.ramp
        t = min(max(t, 0.0), self.duration)
        if t < r:
            u = t / r
            s, ds, _ = _smoothstep(u)
            return w * r * (2.5 * u ** 4 - 3 * u ** 5 + u ** 6), w * s, w * ds / r
        if t <= self.duration - r:
            return w * r / 2 + w * (t - r), w, 0.0
        u = (self.duration - t) / r
        s, ds, _ = _smoothstep(u)
        total = w * self.laps * self.period
        return total - w * r * (2.5 * u ** 4 - 3 * u ** 5 + u ** 6), w * s, -w * ds / r

    def sample(self, t: float) -> FlatState:
        phi, dphi, ddphi = self._phase(t)
        sp, cp, s2, c2 = math.sin(phi), math.cos(phi), math.sin(2 * phi), math.cos(2 * phi)
        p = np.array([self.ax * sp, 0.5 * self.ay * s2, 0.0])
        dp = np.array([self.ax * cp, self.ay * c2, 0.0])  # d/dphi
        ddp = np.array([-self.ax * sp, -2 * self.ay * s2, 0.0])
        return FlatState(np.asarray(self.center, float) + p, dp * dphi, ddp * dphi ** 2 + dp * ddphi,
                         self.yaw, 0.0)


@dataclass(frozen=True)
class Chain:
    """Trajectories flown one after another."""

    parts: tuple

    @property
    def duration(self) -> float:
        return sum(p.duration for p in self.parts)

    def sample(self, t: float) -> FlatState:
        for p in self.parts[:-1]:
            if t < p.duration:
                return p.sample(t)
            t -= p.duration
        return self.parts[-1].sample(t)
