"""Mixer and SE(3) controller on their own: allocation, saturation priority, equilibrium, reference paths."""

import math

import numpy as np
import pytest

from flightrecon.control.mixer import Mixer, allocation_matrix
from flightrecon.control.reference_paths import Chain, FigureEight, MinJerkMove
from flightrecon.control.se3 import SE3Controller
from flightrecon.control.trajectory import FlatState, Trajectory
from flightrecon.errors import ConfigError
from flightrecon.scenario import load_config
from flightrecon.sim.quadrotor import SPIN_SIGN, rotor_positions

POS = rotor_positions(0.17)
MIXER = Mixer(POS, SPIN_SIGN, 0.016, 8.0)


def test_allocation_matches_rotor_physics():
    """Wrench of each rotor alone, from r x F and the spin sign, independently of the matrix code."""
    A = allocation_matrix(POS, SPIN_SIGN, 0.016)
    for i in range(4):
        torque = np.cross(POS[i], [0.0, 0.0, 1.0])
        np.testing.assert_allclose(A[:, i], [1.0, torque[0], torque[1], SPIN_SIGN[i] * 0.016], atol=1e-12)


def test_unsaturated_mix_is_exact():
    cmd = np.array([12.0, 0.1, -0.05, 0.02])
    u = MIXER.mix(cmd[0], cmd[1:])
    np.testing.assert_allclose(MIXER.wrench(u), cmd, atol=1e-9)


def test_saturation_keeps_roll_pitch_and_drops_yaw_first():
    # Full thrust with roll and yaw: the thrust is reduced and yaw given up before roll/pitch.
    u = MIXER.mix(32.0, np.array([0.3, 0.0, 0.5]))
    assert u.min() >= 0.0 and u.max() <= 8.0 + 1e-12
    w = MIXER.wrench(u)
    assert w[1] == pytest.approx(0.3, abs=1e-9) and w[2] == pytest.approx(0.0, abs=1e-9)
    assert 0 <= w[3] < 0.5
    # Torques larger than the motors can span are scaled together: direction kept.
    u = MIXER.mix(16.0, np.array([3.0, -1.5, 0.0]))
    w = MIXER.wrench(u)
    assert u.min() >= -1e-12 and u.max() <= 8.0 + 1e-12
    assert w[1] / w[2] == pytest.approx(-2.0, rel=1e-9)
    # Zero thrust request with a torque: torque still delivered from the bottom of the range.
    w = MIXER.wrench(MIXER.mix(0.0, np.array([0.2, 0.0, 0.0])))
    assert w[1] == pytest.approx(0.2, abs=1e-9)


def _controller(**kw):
    cfg = load_config(None, [f"control.{k}={v}" for k, v in kw.items()])
    return SE3Controller.from_config(cfg, 1.2, np.array([0.012, 0.012, 0.022]), 8.0, 0.3)


def test_hover_equilibrium_needs_only_weight():
    ctl = _controller()
    ref = FlatState(np.array([1.0, 2.0, 1.5]), np.zeros(3), np.zeros(3), 0.7)
    R = np.array([[math.cos(0.7), -math.sin(0.7), 0], [math.sin(0.7), math.cos(0.7), 0], [0, 0, 1]])
    out = ctl.compute(ref.position, np.zeros(3), R, np.zeros(3), ref)
    assert out.thrust == pytest.approx(1.2 * 9.81)
    np.testing.assert_allclose(out.torque, 0.0, atol=1e-12)
    np.testing.assert_allclose(out.R_des, R, atol=1e-12)


def test_tilt_and_thrust_limits_bound_the_desired_force():
    ctl = _controller()
    ref = FlatState(np.array([100.0, 0.0, 100.0]), np.zeros(3), np.zeros(3), 0.0)
    f = ctl.desired_acceleration(np.zeros(3), np.zeros(3), ref)
    assert math.degrees(math.atan2(math.hypot(f[0], f[1]), f[2])) <= 35.0 + 1e-9
    assert np.linalg.norm(f) <= 0.9 * 32.0 / 1.2 + 1e-9
    # A dive command still asks for a positive share of hover thrust (never free fall, b3 defined).
    f = ctl.desired_acceleration(np.zeros(3), np.zeros(3), FlatState(np.array([0, 0, -100.0]), np.zeros(3),
                                                                     np.zeros(3), 0.0))
    assert f[2] > 0


def test_bad_gains_are_config_errors():
    with pytest.raises(ConfigError, match="control.kp"):
        _controller(kp="[1.0, 2.0]")


@pytest.mark.parametrize("traj", [
    MinJerkMove.within_limits([0, 0, 1], [1.5, -0.5, 1.2], 0.0, 2.5, 1.0, 2.0, 8.0, 1.5, 3.0),
    FigureEight(np.array([0.0, 0.0, 1.0]), 1.0, 0.8, 6.0, 2.0, 2.0, 0.3),
    Chain((MinJerkMove([0, 0, 0], [0, 0, 1], 0, 0, 2.0), MinJerkMove([0, 0, 1], [1, 0, 1], 0, 1, 3.0))),
])
def test_reference_derivatives_match_finite_differences(traj):
    assert isinstance(traj, Trajectory)
    ts = np.linspace(0.0, traj.duration, 4001)
    dt = ts[1] - ts[0]
    S = [traj.sample(t) for t in ts]
    P, V, A = (np.array([getattr(s, k) for s in S]) for k in ("position", "velocity", "acceleration"))
    yaw = np.unwrap([s.yaw for s in S])
    np.testing.assert_allclose(np.gradient(P, dt, axis=0)[1:-1], V[1:-1], atol=1e-3)
    np.testing.assert_allclose(np.gradient(V, dt, axis=0)[1:-1], A[1:-1], atol=2e-2)
    np.testing.assert_allclose(np.gradient(yaw, dt)[1:-1], [s.yaw_rate for s in S][1:-1], atol=1e-3)
    np.testing.assert_allclose(V[[0, -1]], 0.0, atol=1e-12)  # rest to rest


def test_min_jerk_move_respects_limits():
    m = MinJerkMove.within_limits([0, 0, 1], [3.0, 1.0, 1.0], 0.0, 3.0, 1.0, 2.0, 8.0, 1.5, 3.0)
    ts = np.linspace(0, m.duration, 2001)
    V = np.array([m.sample(t).velocity for t in ts])
    A = np.array([m.sample(t).acceleration for t in ts])
    assert np.abs(V).max() <= 1.0 + 1e-9 and np.abs(A).max() <= 2.0 + 1e-9
    assert max(abs(m.sample(t).yaw_rate) for t in ts) <= 1.5 + 1e-9
