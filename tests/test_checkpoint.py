"""Versioned checkpoints: the file keeps every value exactly, refuses what it cannot resume with one
clear message, and each component restored from it continues exactly as the uninterrupted one."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch
from test_flight import WALL_X, box_world
from test_occupancy import _raycast_depth, _room

from flightrecon import run_folder
from flightrecon.checkpoint import (FORMAT, FORMAT_VERSION, HEADER, load_checkpoint, refuse_legacy,
                                    save_checkpoint)
from flightrecon.config import MapperConfig
from flightrecon.control.reference_paths import MinJerkMove
from flightrecon.control.trajectory import FlatState
from flightrecon.errors import CheckpointError
from flightrecon.evaluation.coverage import SurfaceCoverage
from flightrecon.geometry import backproject_depth, camera_pose, intrinsics
from flightrecon.mapping.mapper import OnlineMapper
from flightrecon.mapping.store import GaussianMap
from flightrecon.planning.feasibility import Planner
from flightrecon.planning.paths import seed_ompl
from flightrecon.scenario import load_config
from flightrecon.sim.flight import Flight

W, H = 64, 48
START = np.array([0.0, 0.0, 1.2])
WORKSPACE = np.array([[-3.0, -2.5, 0.0], [3.0, 2.5, 3.0]])


@pytest.fixture(scope="module")
def frames():
    """RGB-D views of a room with a crate, ray cast; the color is a pattern of the surface point."""
    mesh = _room()
    K = intrinsics(W, H, 90.0)
    out = []
    for position, yaw in (([0.0, 0.0, 1.2], 0.2), ([0.1, -0.1, 1.3], 0.5), ([-0.2, 0.1, 1.1], -0.3),
                          ([0.0, 0.2, 1.2], 2.0)):
        T = camera_pose(np.array(position), yaw, 10.0)
        depth = _raycast_depth(mesh, K, T, W, H)
        points, valid = backproject_depth(depth, K, T)
        rgb = np.zeros((H, W, 3), np.float32)
        rgb[valid] = 0.5 + 0.4 * np.sin(5.0 * points)
        out.append((rgb, depth, T))
    return K, out


def _round_trip(state: dict, tmp_path) -> dict:
    path = tmp_path / run_folder.CHECKPOINT
    save_checkpoint(path, state)
    return load_checkpoint(path)


# ---------------------------------------------------------------------------------- the file format
def test_values_dtypes_and_shapes_survive_the_file(tmp_path):
    arrays = {"nan_inf": np.array([1.5, np.nan, np.inf, -np.inf]), "empty": np.zeros((0, 3), np.float32),
              "scalar": np.array(7, np.int64), "int64": np.array([2**62, -1], np.int64),
              "bool": np.array([[True, False]]), "half": np.array([0.1, 65504.0, np.nan], np.float16),
              "strided": np.arange(12.0).reshape(3, 4)[:, ::2]}
    tensors = [torch.tensor([1.0, float("nan")]), torch.arange(6, dtype=torch.int16).reshape(2, 3),
               torch.zeros(0, 4), torch.tensor(True)]
    rng = np.random.default_rng(3)
    state = {"arrays": arrays, "tensors": tensors,
             "scalars": {"int": 12, "float": 0.25, "nan": float("nan"), "str": "x/y", "none": None,
                         "flag": False, "rng": rng.bit_generator.state},
             "nested": [[np.ones(2, np.uint8), (1, "two")], []]}
    back = _round_trip(state, tmp_path)
    for name, a in arrays.items():
        assert back["arrays"][name].dtype == a.dtype and back["arrays"][name].shape == a.shape, name
        np.testing.assert_array_equal(back["arrays"][name], a)
    for t, u in zip(tensors, back["tensors"]):
        assert isinstance(u, torch.Tensor) and u.device.type == "cpu" and u.dtype == t.dtype
        assert torch.equal(u.nan_to_num(), t.nan_to_num()) and u.shape == t.shape
    s = back["scalars"]
    assert (s["int"], s["float"], s["str"], s["none"], s["flag"]) == (12, 0.25, "x/y", None, False)
    assert np.isnan(s["nan"])
    again = np.random.default_rng(0)
    again.bit_generator.state = s["rng"]  # an RNG state (128-bit integers) continues the same draws
    assert again.random() == rng.random()
    np.testing.assert_array_equal(back["nested"][0][0], np.ones(2, np.uint8))
    assert back["nested"][0][1] == [1, "two"] and back["nested"][1] == []


def test_unsupported_values_are_refused_when_saving(tmp_path):
    path = tmp_path / run_folder.CHECKPOINT
    for bad in ({"a": np.array([object()])}, {"a": {1: 2}}, {"a": np.int64(3)}, {"a": {"__ndarray__": 1}}):
        with pytest.raises(TypeError):
            save_checkpoint(path, bad)
    assert not path.exists()


def _assert_refused(path, *words):
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(path)
    message = str(err.value)
    assert str(path) in message and "delete" in message, message
    for word in words:
        assert word in message, message


def test_a_truncated_file_is_refused_with_one_clear_message(tmp_path):
    path = tmp_path / run_folder.CHECKPOINT
    save_checkpoint(path, {"a": np.arange(1000.0), "b": 1})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _assert_refused(path, "truncated or corrupt")


def test_another_format_version_is_refused_with_one_clear_message(tmp_path):
    path = tmp_path / run_folder.CHECKPOINT
    header = {"format": FORMAT, "format_version": FORMAT_VERSION + 1, "state": {"a": 1}}
    with open(path, "wb") as f:
        np.savez(f, **{HEADER: np.frombuffer(json.dumps(header).encode(), np.uint8)})
    _assert_refused(path, "newer FlightRecon", f"version {FORMAT_VERSION + 1}", "finish the run")


def test_an_old_pickle_checkpoint_is_refused_unread(tmp_path):
    old = tmp_path / run_folder.LEGACY_CHECKPOINT
    with open(old, "wb") as f:
        pickle.dump({"mission": 1}, f, protocol=pickle.HIGHEST_PROTOCOL)
    _assert_refused(old, "older FlightRecon", "pickle", "finish the run")
    with pytest.raises(CheckpointError, match="pickle") as err:
        refuse_legacy(tmp_path)
    assert str(old) in str(err.value)
    old.unlink()
    refuse_legacy(tmp_path)  # no old checkpoint: nothing to say


def test_a_file_that_is_no_checkpoint_is_refused(tmp_path):
    path = tmp_path / run_folder.CHECKPOINT
    path.write_text("hello")
    _assert_refused(path, "not a FlightRecon checkpoint")


# ---------------------------------------------------------------------------------- the components
def test_a_map_keeps_every_column_through_the_file(tmp_path):
    gmap = GaussianMap(capacity=2)
    gmap.add_column("reliability", (2,), torch.float64, fill=0.5)
    gmap.append(frame=3, means=torch.rand(3, 3), quats=torch.rand(3, 4), log_scales=torch.rand(3, 2),
                opacity_logits=torch.rand(3), colors=torch.rand(3, 3))
    gmap["reliability"][:] = torch.rand(3, 2, dtype=torch.float64)
    back = GaussianMap()
    back.set_state(_round_trip(gmap.get_state(), tmp_path))
    assert len(back) == 3 and list(back._cols) == list(gmap._cols)
    for name in gmap._cols:
        assert back[name].dtype == gmap[name].dtype and torch.equal(back[name], gmap[name]), name
    empty = GaussianMap()
    empty.set_state(_round_trip(GaussianMap().get_state(), tmp_path))
    assert len(empty) == 0 and set(empty._cols) == set(GaussianMap()._cols)


def _mapper() -> OnlineMapper:
    cfg = MapperConfig(backend="cpu", init_subsample=0.3, init_scale_by_resolution=False, k_new=3, k_replay=2,
                       replay="stale", prune_opacity=0.62)
    return OnlineMapper(cfg, near=0.05, far=10.0, seed=5, device="cpu")


def test_a_restored_mapper_continues_bit_identically(frames, tmp_path):
    K, views = frames
    mapper = _mapper()
    for rgb, depth, T in views[:2]:
        mapper.add_frame(rgb, depth, K, T)
    mapper.map.add_column("reliability", (), torch.float32)  # as a selector does
    mapper.map["reliability"][:] = torch.rand(len(mapper.map))
    restored = _mapper()
    restored.set_state(_round_trip(mapper.get_state(), tmp_path))
    for m in (mapper, restored):
        for rgb, depth, T in views[2:]:
            m.add_frame(rgb, depth, K, T)
    assert mapper.pruned > 0 and len(mapper.tombstones) > 0  # the pruning state was carried too
    assert set(restored.map._cols) == set(mapper.map._cols) and len(restored.map) == len(mapper.map)
    for name in mapper.map._cols:  # the splats, the Adam moments and step counts, the selector's column
        assert torch.equal(restored.map[name], mapper.map[name]), name
    assert restored.last_trained == mapper.last_trained and restored._clock == mapper._clock
    assert restored.pruned == mapper.pruned
    np.testing.assert_array_equal(restored.tombstones, mapper.tombstones)
    assert restored.rng.random() == mapper.rng.random()
    assert restored.frame_loss(0) == mapper.frame_loss(0)


def _planner() -> Planner:
    return Planner(load_config(None), WORKSPACE, start_position=START)  # the online occupancy map


def test_a_restored_planner_continues_identically(frames, tmp_path):
    K, views = frames
    planner = _planner()
    for _, depth, T in views[:2]:
        planner.integrate(depth, K, T, body_position=START)
    restored = _planner()
    restored.set_state(_round_trip(planner.get_state(), tmp_path))
    for p in (planner, restored):
        _, depth, T = views[2]
        p.integrate(depth, K, T, body_position=START + 0.1)
    for grid in ("surface", "observed"):
        np.testing.assert_array_equal(getattr(restored.occupancy, grid), getattr(planner.occupancy, grid))
    start = FlatState(START, np.zeros(3), np.zeros(3), 0.0)
    goals = np.array([[0.4, 0.0, 1.0], [0.7, 0.8, 1.0], [0.4, 0.8, 1.2], [1.3, 0.0, 1.2]])
    results = []
    for p in (planner, restored):
        seed_ompl(11)  # as the mission does before each step's check
        results.append(p.check(start, goals, np.zeros(4)))
    a, b = results
    assert [r.reason for r in a] == [r.reason for r in b]
    assert a[0].feasible and a[1].feasible and a[3].reason == "unknown_space"
    assert a[1].used_ompl and b[1].used_ompl  # a detour: the restored clearance field was searched alike
    for r, s in zip(a, b):
        if not r.feasible:
            continue
        t = np.linspace(0.0, r.duration, 20)
        np.testing.assert_array_equal(r.trajectory.evaluate(t)[0], s.trajectory.evaluate(t)[0])


def test_restored_coverage_continues_identically(frames, tmp_path):
    K, views = frames
    surface = backproject_depth(views[3][1], K, views[3][2])[0]
    coverage = SurfaceCoverage(surface)
    coverage.add_frame(views[0][1], K, views[0][2])
    restored = SurfaceCoverage(surface)
    restored.set_state(_round_trip(coverage.get_state(), tmp_path))
    _, depth, T = views[1]
    assert restored.add_frame(depth, K, T) == coverage.add_frame(depth, K, T)
    np.testing.assert_array_equal(restored.observed, coverage.observed)


def _flight(cfg) -> Flight:
    model, data = box_world(cfg)
    return Flight(model, data, cfg)


def test_a_restored_flight_continues_bit_identically(tmp_path):
    cfg = load_config(None, ["sim.pose_noise_pos_m=0.01", "sim.pose_noise_rot_deg=0.5"])
    flight = _flight(cfg)
    flight.start(np.array([WALL_X - 0.5, 0.0, 1.0]))
    move = MinJerkMove.within_limits([WALL_X - 0.5, 0.0, 1.0], [WALL_X + 0.5, 0.0, 1.0], 0.0, 0.3, 1.0, 2.0,
                                     8.0, 1.0, 1.0)
    times = np.arange(int(move.duration / flight.control_dt) + 100) * flight.control_dt
    k = 0
    while not flight.contacts.active:  # checkpoint in contact with the wall and under way
        flight.step(move.sample(times[k]))
        k += 1
    flight.estimated_camera_pose()
    restored = _flight(cfg)
    restored.set_state(_round_trip(flight.get_state(), tmp_path))
    for f in (flight, restored):
        for t in times[k:k + 200]:
            f.step(move.sample(t))
    np.testing.assert_array_equal(restored.log.array, flight.log.array)
    assert restored.log.events == flight.log.events and len(flight.log.events) > 0  # no contact logged twice
    assert restored.last_reference.yaw == flight.last_reference.yaw
    np.testing.assert_array_equal(restored.estimated_camera_pose(), flight.estimated_camera_pose())
