"""The quadrotor flying in the fixed-rate cycle in a small box world: hover, tracking, saturation,
contacts, divergence, and the camera mount."""

import math

import mujoco
import numpy as np
import pytest

from flightrecon.control.reference_paths import FigureEight, MinJerkMove
from flightrecon.control.trajectory import Hold
from flightrecon.geometry import camera_pose_from_body, make_pose
from flightrecon.scenario import load_config
from flightrecon.sim.flight import Flight
from flightrecon.sim.quadrotor import DroneHandle, add_quadrotor
from flightrecon.sim.safety import FlightContact, FlightDiverged

WALL_X = 2.0  # inner face of the wall in front of the drone


def box_world(cfg):
    """Floor plane and one wall (a box whose inner face is at x = WALL_X), with the drone."""
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[10, 10, 0.1])
    spec.worldbody.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.1, 3.0, 1.5],
                            pos=[WALL_X + 0.1, 0.0, 1.5])
    add_quadrotor(spec, cfg)
    model = spec.compile()
    return model, mujoco.MjData(model)


def flight(*overrides, start=(0.0, 0.0, 1.0), yaw=0.0):
    cfg = load_config(None, list(overrides))
    model, data = box_world(cfg)
    f = Flight(model, data, cfg)
    f.start(np.array(start), yaw)
    return f


def yaw_series(log):
    q = log.block("qw", "qx", "qy", "qz")
    return np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))


def test_model_parameters_come_from_config():
    cfg = load_config(None, ["drone.mass=1.4", "drone.arm_length=0.2", "drone.max_motor_thrust=9.0",
                             "drone.motor_time_constant=0.05", "drone.linear_drag=0.5"])
    model, _ = box_world(cfg)
    h = DroneHandle(model)
    assert h.mass == pytest.approx(1.4) and h.max_thrust == pytest.approx(9.0)
    assert h.linear_drag == pytest.approx(0.5)
    np.testing.assert_allclose(np.linalg.norm(h.rotor_positions[:, :2], axis=1), 0.2)
    assert np.all(model.actuator_dynprm[h.motor_ids, 0] == pytest.approx(0.05))
    assert model.dof_damping[h.qvel_adr + 3:h.qvel_adr + 6].max() == 0.0  # rotation is not damped


def test_take_off_then_hover_holds_within_1cm_and_1deg():
    # Take off diagonally while turning 0.4 rad, so every axis has settled from motion.
    f = flight(start=(0.0, 0.0, 0.05), yaw=0.0)
    target = np.array([0.5, -0.3, 1.2])
    f.go_to(target, 0.4)
    assert f.wait_until_arrived()
    log = f.hover(10.0)
    assert log["t"][-1] - log["t"][0] >= 10.0 - 2 * f.control_dt
    assert np.linalg.norm(log.positions - target, axis=1).max() < 0.01
    assert np.degrees(np.abs(yaw_series(log) - 0.4)).max() < 1.0


def test_smooth_step_is_tracked_without_overshoot():
    f = flight()
    move = MinJerkMove.within_limits([0, 0, 1.0], [1.5, 0.5, 1.4], 0.0, 1.0, 1.0, 2.0, 8.0, 1.5, 3.0)
    log = f.fly(move, extra_time=3.0)
    assert log.tracking_rms() < 0.05
    # Overshoot bound: the drone never passes the goal by more than 2 cm along the move direction.
    d = (move.p1 - move.p0) / np.linalg.norm(move.p1 - move.p0)
    assert ((log.positions - move.p1) @ d).max() < 0.02
    assert np.linalg.norm(log.positions[-1] - move.p1) < 0.01
    assert abs(yaw_series(log)[-1] - 1.0) < math.radians(1.0)


@pytest.mark.slow
def test_figure_eight_is_tracked():
    f = flight()
    fig8 = FigureEight(np.array([0.0, 0.0, 1.0]), 1.0, 0.8, 6.0, laps=2.0, ramp=2.0)
    log = f.fly(fig8)
    err = np.linalg.norm(log.positions - log.reference_positions, axis=1)
    assert log.tracking_rms() < 0.05
    assert err.max() < 0.08


def test_thrust_saturation_does_not_flip_the_drone():
    # Weak motors (thrust-to-weight 1.36) and a 4 m jump of the reference: thrust limits bind.
    f = flight("drone.max_motor_thrust=4.0")
    log = f.fly(Hold(np.array([-4.0, 3.0, 2.5]), 1.5, 12.0))
    cmd = log.block("cmd0", "cmd1", "cmd2", "cmd3")
    assert (cmd >= 4.0 - 1e-9).any(axis=1).sum() > 20  # saturated for a while
    R22 = 1 - 2 * (log["qx"] ** 2 + log["qy"] ** 2)
    assert np.degrees(np.arccos(np.clip(R22, -1, 1))).max() < 50.0  # max_tilt 35 deg + transients
    assert np.linalg.norm(log.positions[-1] - [-4.0, 3.0, 2.5]) < 0.1


def test_flying_into_a_wall_records_a_contact():
    f = flight()
    move = MinJerkMove.within_limits([0, 0, 1.0], [WALL_X + 0.5, 0.0, 1.0], 0.0, 0.0, 0.3, 1.0, 4.0, 1.0, 1.0)
    try:
        f.fly(move, extra_time=1.0)
    except FlightDiverged:
        pass  # a crash may tip the drone over; the contact must be logged either way
    events = f.log.events
    assert events, "no contact recorded"
    first = events[0]
    assert first.other_geom == "wall" and first.drone_geom.startswith("drone_")
    assert first.position[0] == pytest.approx(WALL_X, abs=0.02)
    # The drone touched first when its front reached the wall: center one body radius away.
    row = np.searchsorted(f.log["t"], first.time) - 1
    assert WALL_X - f.log["x"][row] < f.cfg.drone.body_radius + 0.02


def test_a_flight_that_stops_on_contact_ends_at_the_first_one():
    f = flight()
    f.stop_on_contact = True  # what sim.on_contact = "stop" sets once the drone is airborne
    move = MinJerkMove.within_limits([0, 0, 1.0], [WALL_X + 0.5, 0.0, 1.0], 0.0, 0.0, 0.3, 1.0, 4.0, 1.0, 1.0)
    with pytest.raises(FlightContact) as err:
        f.fly(move, extra_time=1.0)
    first = err.value.event
    assert f.log.events[0] == first and first.other_geom == "wall"
    assert all(e.time == first.time for e in f.log.events)  # (two rotors may touch in the same step)
    assert str(err.value) == f"the drone touched the scene: {first.describe()}"
    assert f.log["t"][-1] < first.time < f.log["t"][-1] + 1.5 * f.control_dt  # no step after the contact
    assert f.log.slice_from(len(f.log) - 1).events == f.log.events  # the contact belongs to the last step
    assert f.log.slice_from(len(f.log)).events == []


def test_a_rehearsed_flight_is_the_flight_that_follows_and_leaves_no_trace():
    """The oracle is the flight itself: rehearsing a fast diagonal move (its tracking error is what
    the rehearsal is for) returns the positions that flying it then passes, bit for bit; the log,
    the time and the state are as before the rehearsal. A rehearsal into the wall reports the path
    through the contact without raising, though the flight stops on contact, and leaves no event."""
    f = flight()
    f.stop_on_contact = True
    f.hover(0.5)
    before = (len(f.log), f.time, f.state.position.copy())
    move = MinJerkMove.within_limits([0, 0, 1.0], [1.0, 0.6, 1.3], 0.0, 0.8, 1.0, 2.0, 8.0, 1.5, 3.0)
    rehearsed = f.rehearse(move)
    assert (len(f.log), f.time) == before[:2] and np.array_equal(f.state.position, before[2])
    f.fly(move)
    f.wait_until_arrived()
    flown = f.log.positions[before[0]:]
    np.testing.assert_array_equal(rehearsed, flown)
    lag = np.linalg.norm(flown - f.log.reference_positions[before[0]:], axis=1).max()
    assert lag > 0.005  # the drone does lag its reference: what a check of the reference alone misses
    into_wall = MinJerkMove.within_limits(flown[-1], [WALL_X + 0.5, 0.6, 1.3], 0.8, 0.8, 0.3, 1.0, 4.0, 1.0, 1.0)
    n = len(f.log)
    try:
        path = f.rehearse(into_wall)
        assert path[:, 0].max() > WALL_X - f.cfg.drone.body_radius - 0.02
    except FlightDiverged:
        pass  # a crash may tip the drone over: rehearsed, that is said now, and undone all the same
    assert len(f.log) == n and f.log.events == [] and f.stop_on_contact


@pytest.mark.parametrize("upset", ["roll", "nan_state", "nan_motor"])
def test_divergence_stops_with_a_message_and_keeps_the_log(upset):
    f = flight()
    f.hover(0.5)
    h = f.drone
    if upset == "roll":
        f.data.qvel[h.qvel_adr + 3] = 200.0  # violent roll
        match = "tilted"
    elif upset == "nan_state":
        f.data.qpos[h.qpos_adr] = np.nan
        match = "NaN"
    else:
        f.data.act[h.act_adr[0]] = np.nan  # NaN appears inside the physics step; MuJoCo resets
        match = "NaN"
    with pytest.raises(FlightDiverged, match=match) as exc:
        f.hover(2.0)
    assert len(exc.value.log) >= 100 and exc.value.log is f.log
    assert f.log.notes and "diverged" in f.log.notes[0]
    assert f.log["t"][-1] >= 0.5 - 1e-9  # the record up to the failure is kept


@pytest.mark.parametrize("pitch", [0.0, 25.0])
def test_camera_pose_follows_the_body_and_sees_past_the_drone(pitch):
    f = flight(f"camera.pitch_deg={pitch}", "camera.width=64", "camera.height=48", start=(0.0, 0.0, 1.0))
    f.fly(Hold(np.array([0.2, 0.1, 1.1]), 0.3, 0.5))
    s = f.state
    T_wc = f.camera_pose()
    expected = camera_pose_from_body(make_pose(s.R, s.position), f.drone.camera_offset, pitch)
    np.testing.assert_allclose(T_wc, expected, atol=1e-9)
    # Depth of the wall straight ahead: z-depth along the optical axis, no drone geometry in view.
    model, data = f.model, f.data
    with mujoco.Renderer(model, 48, 64) as r:
        r.enable_depth_rendering()
        r.update_scene(data, camera="drone_cam")
        depth = r.render()
    ray = T_wc[:3, 2]
    expected_center = (WALL_X - T_wc[0, 3]) / ray[0] if pitch == 0.0 else None
    if expected_center is not None:
        assert depth[22:26, 30:34].mean() == pytest.approx(expected_center, abs=0.01)
    assert depth.min() > 0.5  # nothing of the drone itself (all within 0.25 m) is rendered


@pytest.mark.slow
def test_flying_into_a_real_scene_records_a_contact_on_its_surface():
    """The world's collision geometry (scene engineer's boxes) stops the drone where the mesh is."""
    import trimesh

    from flightrecon.scene.source import scene_from_config
    from flightrecon.sim.world import build_world
    from flightrecon.rig import takeoff_point

    cfg = load_config("demo", ["camera.width=32", "camera.height=24"])
    scene = scene_from_config(cfg.scene)
    world = build_world(scene, cfg)
    f = Flight.from_world(world, cfg)
    start = takeoff_point(scene, cfg)
    f.start(start, 0.0)
    goal = start + np.array([scene.bounds[1, 0] - start[0] + 0.5, 0.0, 0.0])  # beyond the +x wall
    move = MinJerkMove.within_limits(start, goal, 0.0, 0.0, 0.3, 1.0, 4.0, 1.0, 1.0)
    try:
        f.fly(move, extra_time=1.0)
    except FlightDiverged:
        pass
    assert f.log.events, "no contact with the scene recorded"
    e = f.log.events[0]
    assert e.other_geom.startswith("scene_collision")
    _, dist, _ = trimesh.proximity.ProximityQuery(scene.trimesh).on_surface(np.array([e.position]))
    assert dist[0] < cfg.scene.collision_voxel + 0.03
    assert f.log["x"].max() < goal[0] - 0.3  # it did not pass through


def test_clearance_monitor_is_the_exact_distance_to_the_scene():
    import trimesh

    from flightrecon.sim.safety import ClearanceMonitor

    cfg = load_config(None, [])
    wall = trimesh.creation.box(extents=[0.2, 6.0, 3.0])
    wall.apply_translation([WALL_X + 0.1, 0.0, 1.5])
    model, data = box_world(cfg)
    f = Flight(model, data, cfg, ClearanceMonitor(wall, cfg.drone.body_radius))
    f.start(np.array([0.5, 0.0, 1.5]), 0.0)
    log = f.fly(MinJerkMove([0.5, 0.0, 1.5], [1.2, 0.0, 1.5], 0.0, 0.0, 2.0))
    truth = WALL_X - log["x"] - cfg.drone.body_radius
    np.testing.assert_allclose(log["clearance"], truth, atol=1e-5)  # float32 geometry, not a voxel


def test_arrival_waits_for_settling_and_times_out_when_unreachable():
    f = flight("control.settle_time=0.3")
    f.fly(MinJerkMove([0, 0, 1.0], [0.5, 0, 1.0], 0.0, 0.0, 1.0))
    t_end = f.time
    assert f.wait_until_arrived()
    assert f.time >= t_end + 0.3 - 1e-9
    s = f.state
    assert np.linalg.norm(s.position - [0.5, 0, 1.0]) < f.cfg.control.arrive_pos_tol
    assert np.linalg.norm(s.velocity) < f.cfg.control.arrive_speed_tol
    # A target inside the wall cannot be reached: give up after the timeout, with a note.
    target = Hold(np.array([WALL_X + 0.1, 0.0, 1.0]), 0.0).sample(0.0)
    t0 = f.time
    assert not f.wait_until_arrived(target, timeout=1.0)
    assert f.time - t0 == pytest.approx(1.0, abs=2 * f.control_dt)
    assert "did not settle" in f.log.notes[-1]


def test_pose_noise_has_the_configured_spread_and_truth_is_kept():
    f = flight("sim.pose_noise_pos_m=0.02", "sim.pose_noise_rot_deg=1.0")
    T = f.camera_pose()
    noisy = np.array([f.estimated_camera_pose(T) for _ in range(2000)])
    np.testing.assert_allclose(noisy[:, :3, 3].std(axis=0), 0.02, rtol=0.1)
    ang = np.degrees(np.arccos(np.clip((np.einsum("nij,ij->n", noisy[:, :3, :3], T[:3, :3]) - 1) / 2, -1, 1)))
    # |rotation| of a 3D isotropic Gaussian rotation vector: RMS = sqrt(3) * sigma.
    assert np.sqrt(np.mean(ang ** 2)) == pytest.approx(math.sqrt(3.0), rel=0.1)
    np.testing.assert_allclose(f.camera_pose(), T)  # the simulated pose itself is untouched
    clean = flight()
    np.testing.assert_array_equal(clean.estimated_camera_pose(), clean.camera_pose())


def test_planner_ruckig_trajectory_is_tracked():
    """The planner's jerk-limited trajectories (via-velocities through waypoints) at the configured
    limits are what the active loop flies; they must be tracked as well as the analytic ones."""
    from flightrecon.planning.feasibility import PlanningSettings
    from flightrecon.planning.timing import time_path

    f = flight()
    wp = np.array([[0.0, 0.0, 1.0], [1.0, 0.5, 1.3], [1.5, -0.5, 1.0], [0.5, -1.0, 1.5]])
    yaws = np.array([0.0, 0.8, 1.5, 0.5])
    traj = time_path(wp, yaws, PlanningSettings.from_config(f.cfg).limits)
    assert traj is not None
    log = f.fly(traj, extra_time=1.0)
    assert log.tracking_rms() < 0.05
    assert np.abs(yaw_series(log)[-1] - 0.5) < math.radians(1.0)


def _open_loop(cfg_overrides=()):
    cfg = load_config(None, list(cfg_overrides))
    model, data = box_world(cfg)
    model.opt.timestep = 0.001
    h = DroneHandle(model)
    h.set_pose(model, data, np.array([0.0, 0.0, 1.5]), 0.0)
    return cfg, model, data, h


def test_plant_motor_lag_drag_and_yaw_reaction_follow_their_laws():
    cfg, model, data, h = _open_loop()
    hover = h.mass * 9.81 / 4
    tau, c, k = cfg.drone.motor_time_constant, cfg.drone.linear_drag, cfg.drone.yaw_torque_coeff
    # First-order lag: a step of the command reaches 1 - exp(-t / tau) of the change.
    h.set_motor_commands(data, np.full(4, hover + 2.0))
    n = int(round(tau / model.opt.timestep))
    mujoco.mj_step(model, data, n)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(h.motor_thrusts(data) - hover, 2.0 * (1 - math.exp(-1.0)), rtol=0.02)
    # Linear drag: coasting level at hover thrust, horizontal speed decays as exp(-c t / m).
    cfg, model, data, h = _open_loop()
    data.qvel[h.qvel_adr] = 1.0
    mujoco.mj_step(model, data, 500)
    assert data.qvel[h.qvel_adr] == pytest.approx(math.exp(-c * 0.5 / h.mass), rel=0.01)
    # Yaw reaction: +d on the rotors with spin sign +1, -d on the others, gives Izz * wz' = 4 k d.
    cfg, model, data, h = _open_loop(["drone.motor_time_constant=0.0"])
    d = 0.5
    h.set_motor_commands(data, hover + d * h.spin_sign)
    mujoco.mj_step(model, data, 100)
    wz = data.qvel[h.qvel_adr + 5]
    assert wz == pytest.approx(4 * k * d / h.inertia[2] * 0.1, rel=0.02)
