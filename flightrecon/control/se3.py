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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~40x more on single vectors, and this runs at 200 Hz)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class SE3Controller:
    def __init__(self, mass: float, inertia: np.ndarray, max_total_thrust: float, linear_drag: float,
                 kp: np.ndarray, kv: np.ndarray, kr: np.ndarray, kw: np.ndarray, max_tilt_deg: float,
                 gravity: float = GRAVITY) -> None:
        self.mass = float(mass)
        self.J = np.asarray(inertia, float)
        self.kp, self.kv = np.asarray(kp, float), np.asarray(kv, float)
        self.kr, self.kw = np.asarray(kr, float) * self.J, np.asarray(kw, float) * self.J
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

    def desired_acceleration(self, p: np.ndarray, v: np.ndarray, ref: FlatState) -> np.ndarray:
        """Specific force the rotors should produce (m/s^2, world frame), already limited."""
        a = (-self.kp * (p - ref.position) - self.kv * (v - ref.velocity) + ref.acceleration
             + (self.drag / self.mass) * ref.velocity)
        az = min(max(a[2] + self.g, _MIN_THRUST_SHARE * self.g), self.max_acc)
        h = math.hypot(a[0], a[1])
        h_max = min(az * self.tan_tilt, math.sqrt(max(self.max_acc ** 2 - az * az, 0.0)))
        scale = h_max / h if h > h_max else 1.0
        return np.array([a[0] * scale, a[1] * scale, az])

    def compute(self, p: np.ndarray, v: np.ndarray, R: np.ndarray, omega: np.ndarray, ref: FlatState) -> ControlOutput:
        """Thrust and torques for the state (p, v world; R body-to-world; omega body rates)."""
        f = self.desired_acceleration(p, v, ref)
        b3 = f / math.sqrt(f @ f)
        heading = np.array([math.cos(ref.yaw), math.sin(ref.yaw), 0.0])
        b2 = _cross(b3, heading)
        b2 /= math.sqrt(b2 @ b2)
        R_des = np.array([_cross(b2, b3), b2, b3]).T
        thrust = self.mass * float(f @ R[:, 2])
        M = R_des.T @ R  # R^T R_des is its transpose, so vee(M - M^T) / 2 is the attitude error
        e_R = 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
        # Yaw-rate feed-forward: the reference turns about world z; in body axes that is R^T e3.
        e_w = omega - R[2, :] * ref.yaw_rate
        torque = -self.kr * e_R - self.kw * e_w + _cross(omega, self.J * omega)
        return ControlOutput(max(thrust, 0.0), torque, R_des)
