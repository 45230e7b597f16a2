"""Planned trajectories flown by the SE(3) controller in MuJoCo: no contact, clearance kept."""

from __future__ import annotations

import numpy as np
import pytest

from flightrecon.control.trajectory import FlatState
from flightrecon.planning.feasibility import Planner
from flightrecon.scenario import load_config


@pytest.mark.slow
def test_planned_trajectories_flown_in_mujoco_make_no_contact():
    from flightrecon.scene.source import procedural_scene
    from flightrecon.sim.flight import Flight
    from flightrecon.sim.safety import ClearanceMonitor
    from flightrecon.sim.world import build_world

    cfg = load_config(None, ["scene.name=office0", "planner.use_ground_truth=true"])
    scene = procedural_scene("office0", 0)
    start = np.array([0.0, 0.0, 1.2])
    planner = Planner(cfg, np.array(scene.meta["room_box"]), scene.trimesh, start_position=start)
    world = build_world(scene, cfg)
    flight = Flight.from_world(world, cfg, ClearanceMonitor(scene.trimesh, cfg.drone.body_radius))
    flight.start(start, 0.0)
    flight.hover(0.3)
    rng = np.random.default_rng(0)
    flown = 0
    for _ in range(5):
        s = flight.state
        now = FlatState(s.position, s.velocity, np.zeros(3), s.yaw, 0.0)
        results = [r for r in planner.check_library(now) if r.feasible]
        assert results
        # The longest move of this step (most demanding), and a random one.
        picks = [max(results, key=lambda r: r.length), results[rng.integers(len(results))]]
        for r in picks[:1] if flown % 2 else picks[1:]:
            log = flight.fly(r.trajectory, extra_time=0.3)
            err = np.linalg.norm(log.positions - log.reference_positions, axis=1)
            assert err.max() < 0.1  # the clearance margin (0.1 m) covers the tracking error
            assert np.nanmin(log["clearance"]) > 0.0
            flown += 1
    assert flight.log.events == [], [e.describe() for e in flight.log.events]
    assert flown == 5


@pytest.mark.slow
def test_ompl_detour_around_a_wall_is_flown_without_contact():
    import mujoco
    import trimesh

    from flightrecon.sim.flight import Flight
    from flightrecon.sim.quadrotor import add_quadrotor
    from flightrecon.sim.safety import ClearanceMonitor

    cfg = load_config(None, ["planner.use_ground_truth=true"])
    # The same wall and floor in MuJoCo (collision) and as the planner's ground-truth mesh.
    half = np.array([0.05, 1.0, 1.5])
    center = np.array([0.6, 0.0, 1.5])
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[10, 10, 0.1])
    spec.worldbody.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=center)
    add_quadrotor(spec, cfg)
    model = spec.compile()
    data = mujoco.MjData(model)
    wall = trimesh.creation.box(extents=2 * half)
    wall.apply_translation(center)
    floor = trimesh.creation.box(extents=[8.0, 8.0, 0.1])
    floor.apply_translation([0.0, 0.0, -0.05])
    mesh = trimesh.util.concatenate([wall, floor])
    workspace = np.array([[-2.0, -2.0, 0.0], [3.0, 2.0, 2.5]])
    start = np.array([0.0, 0.2, 1.0])
    planner = Planner(cfg, workspace, mesh, start_position=start)
    flight = Flight(model, data, cfg, ClearanceMonitor(mesh, cfg.drone.body_radius))
    flight.start(start, 0.0)
    flight.hover(0.2)
    s = flight.state
    goal = np.array([1.3, 0.0, 1.0])
    (r,) = planner.check(FlatState(s.position, s.velocity, np.zeros(3), s.yaw, 0.0), goal[None], np.array([0.5]))
    assert r.feasible and r.used_ompl, r.reason
    log = flight.fly(r.trajectory, extra_time=0.5)
    assert flight.log.events == [], [e.describe() for e in flight.log.events]
    assert np.nanmin(log["clearance"]) > 0.0
    assert np.linalg.norm(log.positions[-1] - goal) < 0.05


@pytest.mark.slow
def test_steps_planned_on_the_online_map_keep_clear_of_the_true_scene():
    """Closed loop on what the camera saw: turn in place capturing, then library steps on the map; the
    captures at 320x240 and the frames streamed in flight at planner.look_width (160x120), as in the
    default scenario."""
    from flightrecon.planning.distance_field import DistanceField
    from flightrecon.planning.poses import start_position, workspace_of
    from flightrecon.scene.source import procedural_scene
    from flightrecon.sim.camera import RGBDCamera, reduction_for_width
    from flightrecon.sim.flight import Flight
    from flightrecon.sim.safety import ClearanceMonitor
    from flightrecon.sim.world import build_world

    cfg = load_config(None, ["scene.name=room0", "camera.width=320", "camera.height=240"])
    scene = procedural_scene("room0", 0)
    ws = workspace_of(scene, 2.7)
    start = start_position(scene, cfg.sim.takeoff_height)
    planner = Planner(cfg, ws, start_position=start)  # online occupancy map
    truth = DistanceField.from_mesh(scene.trimesh, cfg.planner.voxel_size, ws + np.array([[-0.5], [0.5]]),
                                    free_seeds=start[None])
    world = build_world(scene, cfg)
    cam = RGBDCamera(world, cfg.camera.width, cfg.camera.height, cfg.camera.hfov_deg, cfg.camera.near, cfg.camera.far)
    flight = Flight.from_world(world, cfg, ClearanceMonitor(scene.trimesh, cfg.drone.body_radius))
    flight.start(start, 0.0)
    rng = np.random.default_rng(1)
    required = cfg.drone.body_radius + cfg.planner.safety_margin

    def capture():
        _, depth, T_wc, _ = flight.capture(cam)
        planner.integrate(depth, cam.K, T_wc, body_position=flight.state.position)

    reduce = reduction_for_width(cfg.camera.width, cfg.camera.height, cfg.planner.look_width)
    assert reduce == 2

    def look():  # as the mission: the camera streams depth in flight
        depth, T_wc = flight.capture_depth(cam, reduce)
        planner.integrate(depth, cam.intrinsics_at(reduce), T_wc, body_position=flight.state.position)

    flight.watch(look, 1.0 / cfg.planner.look_hz)

    def now() -> FlatState:
        s = flight.state
        return FlatState(s.position, s.velocity, np.zeros(3), s.yaw, 0.0)

    def fly(r):
        pos = r.trajectory.evaluate(np.arange(0.0, r.duration, 1e-3))[0][:, :3]
        assert truth.distance(pos).min() >= required - truth.accuracy  # the plan itself is clear
        log = flight.fly(r.trajectory, extra_time=0.3)
        assert np.nanmin(log["clearance"]) > 0.0
        flight.wait_until_arrived()

    capture()
    for k in range(1, 4):  # the mission's initial views: turn in place
        s = now()
        (r,) = planner.check(s, s.position[None], np.array([s.yaw + np.pi / 2]))
        assert r.feasible, r.reason
        fly(r)
        capture()
    moved = 0
    for _ in range(4):
        results = planner.check_library(now())
        moves = [r for r in results if r.feasible and r.length > 0.25]
        assert moves, {r.reason for r in results}
        fly(moves[rng.integers(len(moves))])
        capture()
        moved += 1
    cam.close()
    assert flight.log.events == [], [e.describe() for e in flight.log.events]
    assert moved == 4
