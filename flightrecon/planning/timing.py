"""Jerk-limited timing of a geometric path with ruckig: x, y, z and yaw, ending at rest.

The community ruckig plans one segment at a time offline (intermediate waypoints need its cloud
service), so a path is timed as a chain of segments through its waypoints with chosen via-velocities:
along the bisector of the adjacent legs, slower on sharp turns and short legs. With zero
via-velocities each leg is planned with phase synchronization, which keeps x, y, z on the straight
leg exactly: the fallback when a faster chain leaves the checked corridor.

`JerkTrajectory` stores every axis as piecewise-cubic phases (ruckig's own profiles), so sampling
many times at once is vectorized; it implements the `Trajectory` protocol of flightrecon.control.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization
from ruckig import Trajectory as RuckigTrajectory

from flightrecon.control.trajectory import FlatState


@dataclass(frozen=True)
class Limits:
    """Per-axis kinematic limits (x, y, z share the linear ones; yaw in rad)."""

    vel: float
    acc: float
    jerk: float
    yaw_rate: float
    yaw_acc: float
    yaw_jerk: float

    def arrays(self) -> tuple[list[float], list[float], list[float]]:
        return ([self.vel] * 3 + [self.yaw_rate], [self.acc] * 3 + [self.yaw_acc],
                [self.jerk] * 3 + [self.yaw_jerk])


class JerkTrajectory:
    """Piecewise-cubic (constant-jerk phases) trajectory in x, y, z, yaw; at rest after the end."""

    def __init__(self, starts: list[np.ndarray], coeffs: list[np.ndarray], duration: float):
        # Per axis: phase start times (P,), and (P, 4) rows of p0, v0, a0, jerk.
        self._starts = starts
        self._coeffs = coeffs
        self._duration = float(duration)

    @property
    def duration(self) -> float:
        return self._duration

    def evaluate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration and jerk, each (T, 4) [x, y, z, yaw], at many times."""
        t = np.asarray(times, float).reshape(-1)
        out = _eval_phases(self._starts, self._coeffs, np.clip(t, 0.0, self._duration))
        out[1:, t >= self._duration, :] = 0.0  # at rest after the end
        return out[0], out[1], out[2], out[3]

    def sample(self, t: float) -> FlatState:
        p, v, a, _ = self.evaluate(np.array([t]))
        return FlatState(p[0, :3].copy(), v[0, :3].copy(), a[0, :3].copy(), float(p[0, 3]), float(v[0, 3]))

def _eval_phases(starts: list[np.ndarray], coeffs: list[np.ndarray], t: np.ndarray) -> np.ndarray:
    """(4 derivatives, T, 4 axes) of piecewise-cubic phases at sorted-or-not times `t`."""
    out = np.empty((4, len(t), 4))
    for ax in range(4):
        k = np.clip(np.searchsorted(starts[ax], t, side="right") - 1, 0, len(starts[ax]) - 1)
        dt = t - starts[ax][k]
        p0, v0, a0, j = coeffs[ax][k].T
        out[0, :, ax] = p0 + dt * (v0 + dt * (a0 / 2 + dt * j / 6))
        out[1, :, ax] = v0 + dt * (a0 + dt * j / 2)
        out[2, :, ax] = a0 + dt * j
        out[3, :, ax] = j
    return out


def evaluate_batch(trajs: list[JerkTrajectory], times: list[np.ndarray]) -> np.ndarray:
    """Evaluate many trajectories at their own times (each within [0, duration]) in one vectorized
    pass: (4 derivatives, sum of T_i, 4 axes). Each trajectory's phases are shifted to its own
    time window so one search per axis serves all of them."""
    offsets = np.cumsum([0.0] + [tr.duration + 1.0 for tr in trajs[:-1]])
    starts = [np.concatenate([tr._starts[ax] + o for tr, o in zip(trajs, offsets)]) for ax in range(4)]
    coeffs = [np.concatenate([tr._coeffs[ax] for tr in trajs]) for ax in range(4)]
    t = np.concatenate([np.clip(ti, 0.0, tr.duration) + o for tr, ti, o in zip(trajs, times, offsets)])
    return _eval_phases(starts, coeffs, t)


def _segment(otg: Ruckig, inp: InputParameter, out: RuckigTrajectory):
    result = otg.calculate(inp, out)
    if result not in (Result.Working, Result.Finished):
        return None
    return out


def time_path(waypoints: np.ndarray, yaws: np.ndarray, limits: Limits,
              start_vel: np.ndarray | None = None, start_acc: np.ndarray | None = None,
              stop_at_waypoints: bool = False) -> JerkTrajectory | None:
    """Chain ruckig segments through `waypoints` (W, 3) with headings `yaws` (W,) (already unwrapped
    to be continuous). Starts from the given velocity/acceleration (x, y, z, yaw rate), ends at rest.
    Returns None when ruckig finds no trajectory (e.g. an initial state beyond the limits)."""
    wp = np.asarray(waypoints, float)
    yw = np.asarray(yaws, float)
    n = len(wp)
    vias = np.zeros((n, 4))
    if start_vel is not None:
        vias[0] = start_vel
    if not stop_at_waypoints and n > 2:
        vias[1:-1] = via_velocities(wp, yw, limits)
    acc0 = [0.0] * 4 if start_acc is None else [float(x) for x in start_acc]
    otg = Ruckig(4)
    vmax, amax, jmax = limits.arrays()
    pts = np.concatenate([wp, yw[:, None]], axis=1).tolist()  # plain floats: cheap to hand to ruckig
    vel = vias.tolist()
    starts: list[list[np.ndarray]] = [[] for _ in range(4)]
    coeffs: list[list[np.ndarray]] = [[] for _ in range(4)]
    t0 = 0.0
    acc = acc0
    for i in range(n - 1):
        inp = InputParameter(4)
        inp.current_position, inp.current_velocity, inp.current_acceleration = pts[i], vel[i], acc
        inp.target_position, inp.target_velocity = pts[i + 1], vel[i + 1]
        inp.target_acceleration = [0.0] * 4
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = vmax, amax, jmax
        if not any(vel[i]) and not any(vel[i + 1]) and not any(acc):
            # Rest to rest: phase synchronization keeps x, y, z on the straight leg (ruckig only
            # honours it for all axes together; mixing per-axis modes silently drops it).
            inp.synchronization = Synchronization.Phase
        seg = _segment(otg, inp, RuckigTrajectory(4))
        if seg is None:
            return None
        for ax, profile in enumerate(seg.profiles[0]):
            s, c = _phases(profile)
            starts[ax].append(s + t0)
            coeffs[ax].append(c)
        t0 += seg.duration
        acc = [0.0] * 4
    if n < 2:
        for ax, val in enumerate([*wp[0], yw[0]]):
            starts[ax].append(np.zeros(1))
            coeffs[ax].append(np.array([[val, 0.0, 0.0, 0.0]]))
    return JerkTrajectory([np.concatenate(s) for s in starts], [np.concatenate(c) for c in coeffs], t0)


def _phases(profile) -> tuple[np.ndarray, np.ndarray]:
    """Start times and (p0, v0, a0, jerk) rows of one axis profile, its brake pre-phases included.

    Each attribute read converts a whole C++ array, so every one is read once."""
    durations = np.asarray(profile.t)
    rows = np.empty((8, 4))
    rows[:, 0], rows[:, 1], rows[:, 2] = profile.p, profile.v, profile.a
    rows[:7, 3] = profile.j
    rows[7, 3] = 0.0  # the final state is held after the last phase (exact end values)
    times = np.concatenate([[0.0], np.cumsum(durations)])
    brake = profile.brake
    if brake.duration > 0:
        bt = np.asarray(brake.t)
        keep = bt > 0
        b_rows = np.stack([brake.p, brake.v, brake.a, brake.j], axis=1)[keep]
        b_times = np.concatenate([[0.0], np.cumsum(bt)[:-1]])[keep]
        times = np.concatenate([b_times, times + brake.duration])
        rows = np.concatenate([b_rows, rows])
    return times, rows


def via_velocities(wp: np.ndarray, yaws: np.ndarray, limits: Limits) -> np.ndarray:
    """Velocities (W-2, 4) at the interior waypoints: along the bisector of the adjacent legs, with a
    speed that falls to zero for a U-turn and is limited by what the shorter leg can brake from."""
    d_in = wp[1:-1] - wp[:-2]
    d_out = wp[2:] - wp[1:-1]
    l_in = np.linalg.norm(d_in, axis=1)
    l_out = np.linalg.norm(d_out, axis=1)
    u_in = d_in / np.maximum(l_in, 1e-9)[:, None]
    u_out = d_out / np.maximum(l_out, 1e-9)[:, None]
    bis = u_in + u_out
    nb = np.linalg.norm(bis, axis=1)
    direction = bis / np.maximum(nb, 1e-9)[:, None]
    cos_turn = np.sum(u_in * u_out, axis=1)
    brake_speed = np.sqrt(limits.acc * np.minimum(l_in, l_out))  # half the stopping-distance speed
    speed = np.minimum(limits.vel, brake_speed) * np.clip(cos_turn, 0.0, 1.0)
    v = direction * speed[:, None]
    v = np.clip(v, -limits.vel, limits.vel)
    # Yaw rate at a via point: the mean rate over the two legs' straight-line travel times.
    legs_t = np.maximum((l_in + l_out) / max(limits.vel, 1e-9), 1e-3)
    yaw_rate = np.clip((yaws[2:] - yaws[:-2]) / legs_t, -limits.yaw_rate, limits.yaw_rate) * 0.5
    return np.concatenate([v, yaw_rate[:, None]], axis=1)


def unwrap_yaws(yaw0: float, yaw_goal: float, fractions: np.ndarray) -> np.ndarray:
    """Headings along a path: the shortest turn from yaw0 to yaw_goal, split by path fractions."""
    delta = (yaw_goal - yaw0 + math.pi) % (2 * math.pi) - math.pi
    return yaw0 + delta * np.asarray(fractions, float)
