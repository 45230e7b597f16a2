"""Geometric SE(3) tracking controller (Lee, Leok and McClamroch 2010) for the quadrotor.

Position, velocity and acceleration references (plus the drag the reference velocity will meet)
give the desired force; its direction is the desired body z axis and the reference yaw fixes the
heading. Before that, the force is limited so the desired tilt stays within `max_tilt` and the
thrust within what the rotors can give, trading horizontal acceleration first and never asking for
less than a fraction of hover thrust: the attitude loop then always has a reachable, upright target.
The attitude error on SO(3) and the angular-rate error give body torques; gains are per axis and the
attitude gains are scaled by the inertia, so they read as 1/s^2 and 1/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flightrecon.config import ScenarioConfig
from flightrecon.control.trajectory import FlatState
from flightrecon.errors import ConfigError

GRAVITY = 9.81
_MIN_THRUST_SHARE = 0.3  # of hover: keeps b3 well defined and the drone from free fall


@dataclass(frozen=True)
class ControlOutput:
    thrust: float  # collective thrust (N) along body z
    torque: np.ndarray  # (3,) body torques (N m)
    R_des: np.ndarray  # (3, 3) desired attitude


def _cross(a, b) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _unit(a) -> tuple[float, float, float]:
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] / n, a[1] / n, a[2] / n)


class SE3Controller:
    # The control law runs at 200 Hz on 3-vectors: plain floats cost a fraction of numpy's per-call
    # overhead there, which is most of the flight cycle's Python time.
    def __init__(self, mass: float, inertia: np.ndarray, max_total_thrust: float, linear_drag: float,
                 kp: np.ndarray, kv: np.ndarray, kr: np.ndarray, kw: np.ndarray, max_tilt_deg: float,
                 gravity: float = GRAVITY) -> None:
        self.mass = float(mass)
        self.J = [float(j) for j in inertia]
        self.kp, self.kv = [float(k) for k in kp], [float(k) for k in kv]
        self.kr = [float(k) * j for k, j in zip(kr, self.J)]
        self.kw = [float(k) * j for k, j in zip(kw, self.J)]
        self.g = float(gravity)
        self.drag = float(linear_drag)
        self.tan_tilt = math.tan(math.radians(max_tilt_deg))
        self.max_acc = max_total_thrust / self.mass  # specific thrust limit (m/s^2)

    @classmethod
    def from_config(cls, cfg: ScenarioConfig, mass: float, inertia: np.ndarray, max_motor_thrust: float,
                    linear_drag: float, gravity: float = GRAVITY) -> "SE3Controller":
        c = cfg.control
        for key in ("kp", "kv", "kr", "kw"):
            gains = getattr(c, key)
            if len(gains) != 3 or not all(isinstance(g, (int, float)) and g >= 0 for g in gains):
                raise ConfigError(f"config key 'control.{key}': expected three non-negative numbers, got {gains!r}")
        # 90 % of the rotors' total thrust: the rest is the margin the mixer needs for torques.
        return cls(mass, inertia, 0.9 * 4 * max_motor_thrust, linear_drag, c.kp, c.kv, c.kr, c.kw,
                   cfg.drone.max_tilt_deg, gravity)

    def desired_acceleration(self, p, v, ref: FlatState) -> tuple[float, float, float]:
        """Specific force the rotors should produce (m/s^2, world frame), already limited."""
        rp, rv, ra = ref.position.tolist(), ref.velocity.tolist(), ref.acceleration.tolist()
        c = self.drag / self.mass
        a = [-self.kp[i] * (p[i] - rp[i]) - self.kv[i] * (v[i] - rv[i]) + ra[i] + c * rv[i] for i in range(3)]
        az = min(max(a[2] + self.g, _MIN_THRUST_SHARE * self.g), self.max_acc)
        h = math.hypot(a[0], a[1])
        h_max = min(az * self.tan_tilt, math.sqrt(max(self.max_acc ** 2 - az * az, 0.0)))
        scale = h_max / h if h > h_max else 1.0
        return (a[0] * scale, a[1] * scale, az)

    def compute(self, p, v, R, omega, ref: FlatState) -> ControlOutput:
        """Thrust and torques for the state (p, v world; R body-to-world 3x3; omega body rates)."""
        thrust, torque, R_des = self.compute_floats(np.asarray(p, float).tolist(), np.asarray(v, float).tolist(),
                                                    np.asarray(R, float).reshape(9).tolist(),
                                                    np.asarray(omega, float).tolist(), ref)
        return ControlOutput(thrust, np.array(torque), np.array(R_des).reshape(3, 3).T)

    def compute_floats(self, p: list, v: list, R: list, w: list, ref: FlatState):
        """`compute` on plain floats (R row-major, 9 values): thrust, torque (3,), and R_des as its
        three columns b1, b2, b3."""
        f = self.desired_acceleration(p, v, ref)
        b3 = _unit(f)
        b2 = _unit(_cross(b3, (math.cos(ref.yaw), math.sin(ref.yaw), 0.0)))
        b1 = _cross(b2, b3)
        thrust = self.mass * (f[0] * R[2] + f[1] * R[5] + f[2] * R[8])
        # M = R_des^T R; R^T R_des is its transpose, so vee(M - M^T) / 2 is the attitude error.
        cols = ((R[0], R[3], R[6]), (R[1], R[4], R[7]), (R[2], R[5], R[8]))
        bs = (b1, b2, b3)
        M = [[bs[i][0] * cols[j][0] + bs[i][1] * cols[j][1] + bs[i][2] * cols[j][2] for j in range(3)]
             for i in range(3)]
        e_R = (0.5 * (M[2][1] - M[1][2]), 0.5 * (M[0][2] - M[2][0]), 0.5 * (M[1][0] - M[0][1]))
        # Yaw-rate feed-forward: the reference turns about world z; in body axes that is R^T e3.
        yr = ref.yaw_rate
        e_w = (w[0] - R[6] * yr, w[1] - R[7] * yr, w[2] - R[8] * yr)
        J = self.J
        gyro = _cross(w, (J[0] * w[0], J[1] * w[1], J[2] * w[2]))
        torque = tuple(-self.kr[i] * e_R[i] - self.kw[i] * e_w[i] + gyro[i] for i in range(3))
        return max(thrust, 0.0), torque, (b1, b2, b3)
