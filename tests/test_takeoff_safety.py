"""A take-off point that is safe, and flights that touch the scene are never a silent success.

Scenes are the procedural room0 with furniture boxes added where the drone would take off; the
checks measure clearance independently (trimesh's exact closest points) and fly real MuJoCo
flights through the CLI.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from flightrecon.cli import main
from flightrecon.errors import SceneError
from flightrecon.scenario import load_config
from flightrecon.scene.free_space import room_free_space
from flightrecon.planning.poses import start_position
from flightrecon.rig import flight_region
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import write_replica_ply
from flightrecon.scene.types import Scene
from flightrecon.sim import world

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=8", "mapper.k_replay=4", "evaluation.views=3", "evaluation.every=1"]
KEYS = ("sim.takeoff_height", "drone.body_radius", "planner.safety_margin", "planner.voxel_size", "planner.max_height",
        "scene.up_axis", "scene.up_vector", "scene.unit_scale")
FLOOR_LAYER = 0.03  # m: triangles this close to the floor are the floor (and its rugs)


@pytest.fixture(scope="module")
def room():
    return make_scene("room0", 0)


def furnished(room: Scene, boxes: list[tuple[list[float], list[float]]], meta: dict | None = None) -> Scene:
    """`room` with a box (center, extents) of furniture per entry; `meta` None keeps the room's."""
    vertices, faces, colors = [room.vertices], [room.faces], [room.vertex_colors]
    n = len(room.vertices)
    for center, extents in boxes:
        box = trimesh.creation.box(extents=extents)
        box.apply_translation(center)
        vertices.append(box.vertices)
        faces.append(box.faces + n)
        colors.append(np.full((len(box.vertices), 3), 90, np.uint8))
        n += len(box.vertices)
    return Scene(f"{room.name}_furnished", np.vstack(vertices), np.vstack(faces), vertex_colors=np.vstack(colors),
                 meta=dict(room.meta) if meta is None else meta)


def climb(hover: np.ndarray, floor_z: float, step: float = 0.005) -> np.ndarray:
    """Points of the vertical climb from the floor to `hover`."""
    z = np.arange(floor_z + step, hover[2] + step / 2, step)
    return np.column_stack([np.full_like(z, hover[0]), np.full_like(z, hover[1]), z])


def off_floor(scene: Scene, floor_z: float) -> trimesh.proximity.ProximityQuery:
    """Exact closest points on every triangle but the floor's."""
    low = (scene.vertices[scene.faces][:, :, 2] < floor_z + FLOOR_LAYER).all(axis=1)
    return trimesh.proximity.ProximityQuery(trimesh.Trimesh(scene.vertices, scene.faces[~low], process=False))


# ---------------------------------------------------------------------------------------- take-off point
def test_a_safe_default_take_off_is_kept(room):
    cfg = load_config("demo", [])
    _, takeoff = flight_region(room, cfg)
    default = start_position(room, cfg.sim.takeoff_height)
    np.testing.assert_array_equal(takeoff.hover, default)
    assert not takeoff.moved and takeoff.note == ""
    np.testing.assert_allclose(takeoff.ground, [default[0], default[1], cfg.drone.body_radius / 2])


@pytest.mark.parametrize("extents, why", [([1.2, 1.2, 2.0], "is not in the room's free space"),  # a wardrobe
                                          ([1.0, 1.0, 0.7], "is reached by a climb from the floor")])  # a table
def test_a_take_off_in_furniture_moves_to_the_nearest_safe_point_and_says_why(room, extents, why):
    cfg = load_config("demo", [])
    required = cfg.required_clearance
    at_hover = required + 1.5 * cfg.planner.voxel_size  # what the planner's voxel map needs to see `required`
    scene = furnished(room, [([0.0, 0.0, extents[2] / 2], extents)])  # on the spawn
    _, takeoff = flight_region(scene, cfg)
    default = start_position(scene, cfg.sim.takeoff_height)
    hover = takeoff.hover
    assert takeoff.moved and why in takeoff.note
    assert str(np.round(default, 2).tolist()) in takeoff.note and str(np.round(hover, 2).tolist()) in takeoff.note
    whole = trimesh.proximity.ProximityQuery(scene.trimesh)
    assert whole.on_surface(hover[None])[1][0] >= at_hover
    _, dist, _ = off_floor(scene, 0.0).on_surface(climb(hover, 0.0))
    assert dist.min() >= required  # nothing but the floor comes near the drone from the floor up
    np.testing.assert_allclose(takeoff.ground, [hover[0], hover[1], cfg.drone.body_radius / 2])
    # One grid step closer to the default is too close to the furniture: this is the nearest.
    toward = default - hover
    toward[2] = 0.0
    closer = hover + 0.1 * toward / np.linalg.norm(toward)
    assert (whole.on_surface(closer[None])[1][0] < at_hover
            or off_floor(scene, 0.0).on_surface(climb(closer, 0.0))[1].min() < required)
    # In the room: the free space flooded from the new point fills most of the room's box.
    free = room_free_space(scene, hover)
    room_voxels = np.prod(np.diff(np.asarray(room.meta["room_box"]), axis=0)) / free.pitch ** 3
    assert free.grid.sum() > 0.5 * room_voxels
    np.testing.assert_array_equal(flight_region(scene, cfg)[1].hover, hover)  # deterministic


def test_a_room_too_low_for_the_drone_is_one_error_naming_the_keys(room):
    squash = 0.25  # a 0.7 m high room: the drone needs 2 x 0.35 m
    meta = dict(room.meta)
    meta["ceiling_z"] = room.meta["ceiling_z"] * squash
    meta["room_box"] = (np.asarray(room.meta["room_box"]) * [1, 1, squash]).tolist()
    low = Scene("low", room.vertices * [1, 1, squash], room.faces, vertex_colors=room.vertex_colors, meta=meta)
    with pytest.raises(SceneError) as err:
        flight_region(low, load_config("demo", []))
    text = str(err.value)
    assert "no safe take-off point" in text and "is reached by a climb from the floor" in text
    assert "no point 0.1 m apart in the flight workspace" in text and "0.35 m on its vertical climb" in text
    assert all(key in text for key in KEYS), text


def test_a_drone_too_large_for_the_room_stops_fly_with_the_error_before_flying(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["fly", "demo", "--quiet", "--no-record", "--out", str(out), "--set", "drone.body_radius=1.5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightrecon: error: scene 'room0' has no safe take-off point: the default hover point "
                          "[0.0, 0.0, 1.2] (sim.takeoff_height = 1.2 m above the floor at z = 0.00 m) has "), err
    assert "m it needs (drone.body_radius + planner.safety_margin, and 1.5 planner.voxel_size" in err
    assert "(the room shrunk by the clearance) is empty" in err
    assert all(key in err for key in KEYS), err
    assert not out.exists()


# ---------------------------------------------------------------------------------------- flights
def _fly(tmp_path: Path, capsys, scene: Scene, name: str, *sets: str) -> tuple[int, str, str, Path]:
    ply = write_replica_ply(scene, tmp_path / f"{scene.name}.ply")
    out = tmp_path / name
    args = ["fly", "demo", "--quiet", "--no-record", "--out", str(out)]
    for s in TINY + [f"scene.path={ply}", "scene.up_axis=z", *sets]:
        args += ["--set", s]
    rc = main(args)
    captured = capsys.readouterr()
    return rc, captured.out, captured.err, out


@pytest.mark.slow
def test_a_flight_from_a_blocked_spawn_takes_off_from_the_safe_point(room, tmp_path, capsys, caplog):
    lo, hi = room.bounds
    center = (lo + hi) / 2  # where a scan without a spawn takes off
    scene = furnished(room, [([center[0], center[1], 1.0], [1.2, 1.2, 2.0])], meta={})  # a wardrobe
    rc, out, err, run = _fly(tmp_path, capsys, scene, "run", "budget.frames=3", "budget.initial_views=2")
    assert rc == 0, err
    assert any(r.levelname == "WARNING" and r.getMessage().startswith("take-off moved: the default hover point")
               for r in caplog.records)
    events = (run / "events.log").read_text()
    assert "take-off moved" in events and "is not in the room's free space" in events
    with open(run / "trajectory.csv") as f:
        first = next(csv.DictReader(f))
    x, y, z = (float(first[k]) for k in "xyz")
    assert max(abs(x - center[0]), abs(y - center[1])) >= 0.6 + load_config("demo").required_clearance
    assert z < 0.2  # it rested on the floor, then climbed
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["contacts"] == 0 and metrics["contact_frames"] == []
    assert "0 contacts" in out and "WARNING" not in err
    assert all("cannot leave its take-off point" not in r.getMessage() for r in caplog.records)


@pytest.fixture
def glass_pane(room, tmp_path, monkeypatch) -> tuple[Scene, list[str]]:
    """A glass pane across the room 0.4 m ahead of the take-off point at its height: a MuJoCo box the
    drone collides with and the camera never draws (the collision group), as no depth camera sees
    glass. The only candidate flies 0.3 m forward, into it: a flight that touches what it could not
    see must still say so."""
    lo, hi = room.bounds
    center = (lo + hi) / 2
    add_scene = world.add_scene

    def with_pane(spec, scene, baked, ambient=0.3):
        add_scene(spec, scene, baked, ambient)
        spec.worldbody.add_geom(name="glass", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[center[0] + 0.42, center[1], 1.2],
                                size=[0.01, 1.5, 0.5], contype=1, conaffinity=1, group=world.COLLISION_GROUP)

    monkeypatch.setattr(world, "add_scene", with_pane)
    library = tmp_path / "forward.toml"
    library.write_text("[[candidate]]\nforward = 0.3\n")
    return room, [f"planner.library={library}", "budget.frames=3", "budget.initial_views=1", "planner.max_vel=0.3"]


@pytest.mark.slow
def test_a_flight_that_touches_the_scene_stops_naming_the_frame(glass_pane, tmp_path, capsys):
    scene, sets = glass_pane
    rc, out, err, run = _fly(tmp_path, capsys, scene, "run", *sets)
    assert rc == 2
    assert "flightrecon: error: frame 0: the flight stopped: the drone touched the scene: t=" in err, err
    assert "sim.on_contact" in err and "planner.safety_margin" in err
    failed = (run / "failed.txt").read_text()
    assert failed.startswith("frame 0: the flight stopped: the drone touched the scene") and "contact drone_" in failed
    assert "frame 0: the flight stopped" in (run / "events.log").read_text()
    assert (run / "frames.csv").is_file() and not (run / "metrics.json").exists()


@pytest.mark.slow
def test_a_flight_told_to_continue_counts_its_contacts_loudly(glass_pane, tmp_path, capsys):
    scene, sets = glass_pane
    rc, out, err, run = _fly(tmp_path, capsys, scene, "run", *sets, "sim.on_contact=continue")
    assert rc == 0, err
    metrics = json.loads((run / "metrics.json").read_text())
    n = metrics["contacts"]
    assert n >= 1 and metrics["contact_frames"][0] == 0
    low = metrics["min_clearance_m"]
    assert f"{n} contacts, lowest clearance {low:.3f} m (margin 0.1 m) -> {run}" in out
    assert f"WARNING: the drone touched the scene {n} time(s) (frames {metrics['contact_frames']}" in err
    # the margin's own record: the frames inside it, the lowest clearance, said on stderr
    with open(run / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    flown = [(int(r["frame"]), float(r["min_clearance"])) for r in rows if r["min_clearance"] not in ("", "nan")]
    assert low == pytest.approx(min(c for _, c in flown), abs=1e-5)  # (to the mesh: the pane is not in it)
    assert metrics["margin_breach_frames"] == [k for k, c in flown if c < 0.1]
    assert ("WARNING: the drone came within" in err) == bool(metrics["margin_breach_frames"])
    assert "frame 0: contact t=" in (run / "events.log").read_text()
    assert not (run / "failed.txt").exists()
