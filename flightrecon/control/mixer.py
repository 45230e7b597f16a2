"""Motor mixing: collective thrust and body torques -> the four rotor thrusts, within their limits.

When the limits bind, the wrench cannot be met exactly and something must give. Roll and pitch
torques keep the drone upright, so they come first: the collective thrust is shifted (or, if the
torques alone span more than the thrust range, the torques are scaled down together, keeping their
direction); the yaw torque, the weakest and least urgent axis, gets only the margin that is left.
This keeps attitude stable when thrust saturates instead of flipping the drone.
"""

from __future__ import annotations

import numpy as np


def allocation_matrix(rotor_positions: np.ndarray, spin_sign: np.ndarray, yaw_torque_coeff: float) -> np.ndarray:
    """(4, 4) A with [thrust, Mx, My, Mz] = A @ rotor_thrusts, for rotors pushing along body z."""
    p = np.asarray(rotor_positions, float)
    return np.stack([np.ones(4), p[:, 1], -p[:, 0], np.asarray(spin_sign, float) * yaw_torque_coeff])


class Mixer:
    """Wrench -> rotor thrusts in [0, max_thrust] with the priority described in the module doc."""

    def __init__(self, rotor_positions: np.ndarray, spin_sign: np.ndarray, yaw_torque_coeff: float,
                 max_thrust: float) -> None:
        self.A = allocation_matrix(rotor_positions, spin_sign, yaw_torque_coeff)
        self.A_inv = np.linalg.inv(self.A)
        self.max_thrust = float(max_thrust)
        self._A_inv_rows = self.A_inv.tolist()  # plain floats: this runs at the control rate

    def wrench(self, thrusts: np.ndarray) -> np.ndarray:
        """[thrust, Mx, My, Mz] produced by rotor thrusts."""
        return self.A @ thrusts

    def mix(self, thrust: float, torque) -> np.ndarray:
        """Rotor thrusts for the collective `thrust` (N) and body `torque` (N m), saturated by priority."""
        fmax = self.max_thrust
        A = self._A_inv_rows
        tx, ty, tz = float(torque[0]), float(torque[1]), float(torque[2])
        u = [r[0] * thrust + r[1] * tx + r[2] * ty + r[3] * tz for r in A]
        if min(u) >= 0.0 and max(u) <= fmax:
            return np.array(u)
        # Roll/pitch differential thrusts (zero sum) and the collective share per rotor.
        d = [r[1] * tx + r[2] * ty for r in A]
        span = max(d) - min(d)
        if span > fmax:
            d = [x * fmax / span for x in d]
            base = -min(d)
        else:
            base = min(max(thrust / 4.0, -min(d)), fmax - max(d))
        u = [base + x for x in d]
        # Yaw: the largest fraction of the requested yaw differential that still fits.
        y = [r[3] * tz for r in A]
        alpha = 1.0
        for ui, yi in zip(u, y):
            if yi > 1e-12:
                alpha = min(alpha, (fmax - ui) / yi)
            elif yi < -1e-12:
                alpha = min(alpha, -ui / yi)
        alpha = max(alpha, 0.0)
        return np.clip(np.array([ui + alpha * yi for ui, yi in zip(u, y)]), 0.0, fmax)
