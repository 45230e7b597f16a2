"""Scan-like test scenes (`scene.scanify`): the fused surface lies on the true room where it was
seen, the truth sidecar brings any stored frame back to the room's floor, crops and holes are where
asked, furniture stands on the take-off spot, the same inputs give the same bytes, and every format
reads back through the loader and `scene info`."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from flightrecon.cli import build_parser, main as cli_main
from flightrecon.commands.scene import scan_options
from flightrecon.errors import SceneError
from flightrecon.geometry import camera_pose, intrinsics
from flightrecon.planning.poses import start_position
from flightrecon.scene import load_scene
from flightrecon.scene.handheld import RaycastCamera, Sensor, handheld_walk, sensor_depth
from flightrecon.scene.levels import scene_levels
from flightrecon.scene.loaders import META_FILE
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.scanify import (RAGGED, Scan, ScanOptions, read_truth, scan_subject, scanify, truth_path,
                                       write_scan)
from flightrecon.scene.surface_distance import SurfaceDistance
from flightrecon.scene.texture_atlas import per_triangle_atlas

SMALL = ScanOptions(frames=30, voxel=0.05, max_faces=None, sensor=Sensor(width=96, height=72))


@pytest.fixture(scope="module")
def room():
    return make_scene("room1", 0)


@pytest.fixture(scope="module")
def scans(room) -> dict:
    """Small scans of room1, one per variant the tests look at."""
    variants = {"z-up": SMALL, "camera": replace(SMALL, convention="camera"),
                "y-up-cm": replace(SMALL, convention="y-up", units="cm", heading_deg=30.0),
                "-y-up-mm": replace(SMALL, convention="-y-up", units="mm", offset=(0.4, -0.2, 0.7)),
                "no-ceiling": replace(SMALL, ceiling="none"), "low-walls": replace(SMALL, wall_top=1.7),
                "holes": replace(SMALL, holes=6), "furniture": replace(SMALL, furniture=True)}
    return {k: scanify(room, o, seed=0) for k, o in variants.items()}


def _world(scan) -> np.ndarray:
    """The scan's vertices back in the procedural world (m), through the truth's transform."""
    T = np.asarray(scan.truth["file_from_world"])
    return (scan.vertices - T[:3, 3]) @ np.linalg.inv(T[:3, :3]).T


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    return float(trimesh.Trimesh(vertices, faces, process=False).area)


def test_the_fused_surface_lies_on_the_true_room_where_it_was_seen(room, scans):
    scan = scans["z-up"]
    d = SurfaceDistance(room).distance(_world(scan))
    assert np.median(d) < 0.01 and np.percentile(d, 95) < 0.03  # lumpy, but on the room
    # and the colours are the room's: each vertex's colour against the nearest true vertex's
    _, nearest = trimesh.proximity.ProximityQuery(room.trimesh).vertex(_world(scan)[::20])
    diff = np.abs(scan.vertex_colors[::20].astype(float) - room.vertex_colors[nearest].astype(float))
    assert np.median(diff) < 25


@pytest.mark.parametrize("variant", ["z-up", "camera", "y-up-cm", "-y-up-mm"])
def test_the_truth_brings_the_stored_scan_back_level_with_the_floor_where_it_is(room, scans, variant, tmp_path):
    scan = scans[variant]
    path = write_scan(scan, tmp_path / "scan.ply")[0]
    truth = read_truth(path)
    assert np.isclose(np.linalg.norm(truth["up"]), 1.0)
    # read as a real scan would be, told only the truth's up vector and units
    leveled = load_scene(path, up_vector=truth["up"], unit_scale=truth["meters_per_unit"])
    floor = scene_levels(leveled).floor_z  # from the geometry: the lowest large level layer
    assert floor == pytest.approx(truth["floor"] * truth["meters_per_unit"], abs=0.02)
    height = np.ptp(leveled.vertices[:, 2])
    assert height == pytest.approx(room.meta["ceiling_z"] - room.meta["floor_z"], abs=0.1)
    # the transform takes the procedural floor to the truth's floor height along up
    T = np.asarray(truth["file_from_world"])
    assert float(np.dot(truth["up"], T[:3, :3] @ [1.0, -0.5, room.meta["floor_z"]] + T[:3, 3])) == \
        pytest.approx(truth["floor"], rel=1e-9, abs=1e-9)


def test_the_conventions_store_the_same_surface(scans):
    ref = _world(scans["z-up"])
    for variant in ("y-up-cm", "-y-up-mm"):
        np.testing.assert_allclose(_world(scans[variant]), ref, atol=1e-6)
    assert scans["y-up-cm"].truth["up"] == [0.0, 1.0, 0.0] and scans["y-up-cm"].truth["units"] == "cm"
    assert scans["-y-up-mm"].truth["up"] == pytest.approx([0.0, -1.0, 0.0])
    assert scans["-y-up-mm"].truth["floor"] == pytest.approx(700.0)  # the offset's 0.7 m, in mm


def test_the_camera_frame_scan_has_its_up_along_no_axis(scans):
    up = np.asarray(scans["camera"].truth["up"])
    angles = np.degrees(np.arccos(np.clip(np.abs(up), 0.0, 1.0)))  # to each axis, either sign
    assert angles.min() > 10.0
    assert scans["camera"].truth["kinds"] == sorted({"camera", "m", "ceiling", "turned"})


def test_no_ceiling_and_low_walls_are_cropped(room, scans):
    ceiling = room.meta["ceiling_z"]
    full = _world(scans["z-up"])[:, 2]
    assert (full > ceiling - 0.1).sum() > 100  # looking up, the ceiling was scanned
    z = _world(scans["no-ceiling"])[:, 2]
    assert z.max() < ceiling - 0.05 and (z > ceiling - 0.4).sum() > 100  # walls still reach near it
    z = _world(scans["low-walls"])[:, 2]
    assert z.max() <= 1.7 + RAGGED + 0.01 and (z > 1.55).sum() > 100
    assert scans["low-walls"].truth["top"] == pytest.approx(1.7)
    assert {"no-ceiling", "low-walls"} <= set(scans["low-walls"].truth["kinds"])


def test_a_scan_has_holes_and_cut_holes_take_more(room, scans):
    plain, holey = scans["z-up"], scans["holes"]
    mesh = trimesh.Trimesh(plain.vertices, plain.faces, process=False)
    assert not mesh.is_watertight
    assert mesh.area < 0.95 * room.trimesh.area  # unseen surface is missing
    assert _area(holey.vertices, holey.faces) < _area(plain.vertices, plain.faces) - 6 * math.pi * 0.15 ** 2 * 0.5


def test_furniture_stands_where_the_default_take_off_point_is(room, scans, tmp_path):
    for variant, blocked in (("furniture", True), ("z-up", False)):
        path = write_scan(scans[variant], tmp_path / f"{variant}.ply")[0]
        truth = read_truth(path)
        scan = load_scene(path, up_vector=truth["up"], unit_scale=truth["meters_per_unit"])
        takeoff = start_position(scan, 1.2)  # the loader's default for a scan: above the floor's center
        clearance = SurfaceDistance(scan).distance(takeoff[None])[0]
        assert (clearance < 0.3) if blocked else (clearance > 0.5), (variant, clearance)
        assert np.linalg.norm(takeoff - truth["takeoff_point"]) < 0.3
    box = scan_subject(room, replace(SMALL, furniture=True), 0)
    assert len(box.faces) > len(room.faces) and box.meta["furniture"]["size_m"][2] >= 0.9


def test_the_same_inputs_give_the_same_bytes(room, scans, tmp_path):
    again = scanify(room, replace(SMALL, convention="camera"), seed=0)
    ref = scans["camera"]
    assert np.array_equal(again.vertices, ref.vertices) and np.array_equal(again.faces, ref.faces)
    assert np.array_equal(again.vertex_colors, ref.vertex_colors) and again.truth == ref.truth
    for suffix in (".ply", ".obj"):
        a = write_scan(ref, tmp_path / "a" / f"scan{suffix}")
        b = write_scan(again, tmp_path / "b" / f"scan{suffix}")
        for pa, pb in zip(a, b):
            assert pa.read_bytes() == pb.read_bytes(), pa.name
    other = scanify(room, replace(SMALL, convention="camera"), seed=1)
    assert len(other.vertices) != len(ref.vertices) or not np.array_equal(other.vertices, ref.vertices)


def test_every_format_reads_back_through_the_loader_and_scene_info(scans, tmp_path, capsys):
    scan = scans["-y-up-mm"]
    for suffix, appearance in ((".ply", "vertex colors"), (".obj", "texture")):
        written = write_scan(scan, tmp_path / f"scan{suffix}")
        assert written[-1] == truth_path(written[0]) and written[-1].name == f"scan{suffix}.truth.json"
        assert not (tmp_path / META_FILE).exists()
        loaded = load_scene(written[0], unit_scale=0.001)
        assert loaded.appearance == appearance and len(loaded.faces) == len(scan.faces)
        assert "floor_z" not in loaded.meta and "up" not in loaded.meta  # the loader never reads the truth
        assert cli_main(["scene", "info", str(written[0]), "--unit-scale", "0.001", "--up-vector", "0", "-1", "0",
                         "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        assert info["appearance"] == appearance and info["triangles"] == len(scan.faces)
        assert info["floor_z"] == pytest.approx(0.7, abs=0.03)  # the offset's 0.7 m
        assert read_truth(written[0])["appearance"] == {".ply": "colors", ".obj": "texture"}[suffix]
    obj = load_scene(tmp_path / "scan.obj", unit_scale=0.001)
    ply = load_scene(tmp_path / "scan.ply", unit_scale=0.001)
    assert obj.texture.std() > 5  # the atlas shows the room's colours, not a blank
    assert abs(obj.texture.reshape(-1, 3).mean(0) - ply.vertex_colors.mean(0)).max() < 20


def test_the_atlas_shows_each_triangles_corner_colours():
    rng = np.random.default_rng(0)
    v = rng.uniform(0, 1, (30, 3))
    f = np.stack([rng.permutation(30)[:3] for _ in range(41)])  # an odd count: the last cell is half used
    c = rng.integers(0, 256, (30, 3)).astype(np.uint8)
    verts, faces, uv, image = per_triangle_atlas(v, f, c)
    np.testing.assert_array_equal(verts[faces], v[f])
    # each corner's UV is the centre of a pixel painted with that corner's colour
    H, W = image.shape[:2]
    px = np.stack([uv[:, 0] * W, (1 - uv[:, 1]) * H], 1)
    np.testing.assert_allclose(px % 1, 0.5, atol=1e-9)
    got = image[px[:, 1].astype(int), px[:, 0].astype(int)]
    np.testing.assert_array_equal(got, c[f].reshape(-1, 3))
    # and halfway along each side the colour is halfway between its corners' colours
    corner = px.reshape(-1, 3, 2)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        mid = ((corner[:, a] + corner[:, b]) / 2).astype(int)
        want = (c[f[:, a]].astype(float) + c[f[:, b]]) / 2
        assert np.abs(image[mid[:, 1], mid[:, 0]] - want).max() <= 0.5


def test_the_sensor_loses_far_grazing_and_random_pixels_and_its_noise_grows_with_depth():
    sensor = Sensor()
    rng = np.random.default_rng(0)
    z = np.full((200, 200), 3.0)
    cos = np.ones_like(z)
    cos[:, :20] = 0.1  # grazing
    z[:20] = 6.0  # beyond range
    d = sensor_depth(z, cos, sensor, rng)
    assert (d[:, :20] == 0).all() and (d[:20] == 0).all()
    inner = d[40:-40, 40:-40]
    lost = (inner == 0).mean()
    assert 0.01 < lost < 0.04
    kept = inner[inner > 0]
    assert np.std(kept) == pytest.approx(sensor.noise_sigma(3.0), rel=0.1)


def test_the_hand_held_walk_stays_at_chest_height_and_looks_up_only_when_asked():
    for look_up in (False, True):
        T = handheld_walk(np.array([0.0, 0.0, 0.5]), np.array([2.0, 1.5]), 60, np.random.default_rng(0),
                          look_up=look_up)
        assert T.shape == (60, 4, 4)
        height = T[:, 2, 3] - 0.5
        assert height.min() > 1.15 and height.max() < 1.75
        elevation = np.degrees(np.arcsin(T[:, 2, 2]))  # of the optical axis
        assert (elevation.max() > 25) == look_up
        assert elevation.min() < -25


def test_rendered_depth_is_z_depth_and_colour_is_the_surface_colour():
    # a wall at x = 2 facing a camera at the origin looking along +x
    wall = trimesh.creation.box(extents=[0.1, 10, 10])
    wall.apply_translation([2.05, 0, 0])
    colors = np.tile([[200, 100, 50]], (len(wall.vertices), 1)).astype(np.uint8)
    sensor = Sensor(width=32, height=24)
    cam = RaycastCamera(wall, colors, sensor)
    depth, rgb, cos = cam.render(camera_pose(np.zeros(3), 0.0))
    np.testing.assert_allclose(depth, 2.0, atol=1e-5)
    np.testing.assert_allclose(rgb, np.broadcast_to([200 / 255, 100 / 255, 50 / 255], rgb.shape), atol=1e-5)
    assert cos.min() > 0.6 and cos.max() <= 1.0
    assert sensor.K[0, 0] == pytest.approx(intrinsics(32, 24, 65.0)[0, 0])
    assert cam.clearance(np.array([[0.0, 0.0, 0.0]]))[0] == pytest.approx(2.0, abs=1e-5)


def test_bad_options_say_how_to_fix_them():
    with pytest.raises(SceneError, match="choose one of camera, y-up, -y-up, z-up"):
        ScanOptions(convention="x-up")
    with pytest.raises(SceneError, match="choose another convention"):
        ScanOptions(convention="camera", heading_deg=10.0)
    with pytest.raises(SceneError, match="wall_top"):
        ScanOptions(wall_top=0.1)
    with pytest.raises(SceneError, match=r"max_faces >= 1000 \(or None\)"):
        ScanOptions(max_faces=0)
    with pytest.raises(SceneError, match=r"\.ply .* or \.obj"):
        write_scan(Scan(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((3, 3), np.uint8), {"kinds": []}),
                   Path("scan.glb"))
    with pytest.raises(SceneError, match="scan truth .* not found"):
        read_truth("/nonexistent/scan.ply")


def test_the_cli_defaults_are_scan_options_defaults():
    args = build_parser().parse_args(["scene", "scanify", "room0", "--out", "x.ply"])
    assert scan_options(args) == ScanOptions()
    args = build_parser().parse_args(["scene", "scanify", "room0", "--out", "x.ply", "--convention=-y-up",
                                      "--max-faces", "0", "--offset", "1", "2", "3", "--furniture"])
    assert scan_options(args) == ScanOptions(convention="-y-up", max_faces=None, offset=(1.0, 2.0, 3.0),
                                             furniture=True)


@pytest.mark.slow
def test_cli_scanify_writes_a_scan_and_its_truth(tmp_path, capsys):
    out = tmp_path / "scan" / "room2.obj"
    assert cli_main(["scene", "scanify", "room2", "--out", str(out), "--convention=-y-up", "--units", "mm",
                     "--wall-top", "1.9", "--frames", "30", "--voxel", "0.05", "--max-faces", "20000"]) == 0
    text = capsys.readouterr().out
    assert "room2.obj" in text and "up (0.000, -1.000, 0.000)" in text
    assert {p.name for p in out.parent.iterdir()} == {"room2.obj", "room2.mtl", "room2.png", "room2.obj.truth.json"}
    truth = read_truth(out)
    assert truth["scene"] == "room2" and truth["units"] == "mm" and truth["appearance"] == "texture"
    assert {"-y-up", "mm", "low-walls", "no-ceiling", "texture"} <= set(truth["kinds"])
    assert truth["options"]["wall_top"] == 1.9
    assert cli_main(["scene", "scanify", "room2", "--out", str(tmp_path / "x.ply"), "--units", "inch"]) == 2
    assert "choose one of m, cm, mm" in capsys.readouterr().err


@pytest.mark.slow
def test_the_corpus_covers_every_scene_and_kind_and_its_truth_holds():
    from scan_corpus import corpus_specs, scan_corpus, select
    from flightrecon.scene.procedural import SCENE_NAMES

    records = scan_corpus()
    assert len(records) == len(corpus_specs()) >= 40
    assert {r.scene for r in records} == set(SCENE_NAMES)
    kinds = set().union(*(r.kinds for r in records))
    assert {"camera", "y-up", "-y-up", "z-up", "ceiling", "partial-ceiling", "no-ceiling", "low-walls", "holes",
            "colors", "texture", "m", "cm", "mm", "furniture", "turned"} <= kinds
    assert select(records, "camera", "texture", exclude=("furniture",)) == \
        [r for r in records if r.has("camera", "texture") and "furniture" not in r.kinds]
    for r in records:
        assert r.path.is_file() and np.isclose(np.linalg.norm(r.up), 1.0)
        scan = load_scene(r.path, up_vector=r.up, unit_scale=r.meters_per_unit)
        assert scene_levels(scan).floor_z == pytest.approx(r.floor * r.meters_per_unit, abs=0.03), r.path.name
        if r.has("camera"):
            assert np.degrees(np.arccos(np.abs(r.up).max())) > 10.0, r.path.name
        clearance = SurfaceDistance(scan).distance(start_position(scan, 1.2)[None])[0]
        assert (clearance < 0.3) == r.has("furniture"), (r.path.name, clearance)
