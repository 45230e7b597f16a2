"""Scans without a ceiling (walls cut low, as in ScanNet-style scans): floor and ceiling detection,
the workspace the planner uses, a flight that moves every frame, and a clear word when the
workspace leaves the drone no room. The scene is a procedural room with its ceiling removed and
walls cut to 1.4 m, written in Replica's format without metadata, so only its geometry speaks."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from flightrecon.planning.poses import start_position, workspace_of
from flightrecon.scene import load_scene
from flightrecon.scene.levels import scene_levels
from flightrecon.scene.procedural import make_scene
from flightrecon.scene.replica_ply import write_replica_ply
from flightrecon.scene.types import Scene

ROOT = Path(__file__).resolve().parents[1]
WALL_TOP = 1.4


@pytest.fixture(scope="module")
def open_scan(tmp_path_factory) -> Path:
    room = make_scene("room0", 0)
    above = (room.vertices[room.faces][:, :, 2] > WALL_TOP + 1e-6).all(axis=1)  # ceiling, upper walls
    vertices = room.vertices.copy()
    vertices[:, 2] = np.minimum(vertices[:, 2], WALL_TOP)
    scan = Scene("room0_open", vertices, room.faces[~above], vertex_colors=room.vertex_colors)
    return write_replica_ply(scan, tmp_path_factory.mktemp("open") / "mesh.ply")


@pytest.mark.parametrize("name", ["office0", "room1"])
def test_geometry_finds_the_floor_and_ceiling_the_generator_wrote(name):
    room = make_scene(name, 0)
    bare = Scene(name, room.vertices, room.faces)  # no metadata: geometry alone
    levels = scene_levels(bare)
    assert levels.source == "geometry"
    assert abs(levels.floor_z - room.meta["floor_z"]) < 0.01  # rugs lie a few mm above the floor
    assert abs(levels.ceiling_z - room.meta["ceiling_z"]) < 0.01


def test_an_open_scan_has_no_ceiling_and_a_capped_workspace(open_scan):
    scan = load_scene(open_scan)
    levels = scene_levels(scan)
    assert levels.ceiling_z is None and abs(levels.floor_z) < 0.01
    work = workspace_of(scan, max_height=2.5)
    np.testing.assert_allclose(work[:, :2], scan.bounds[:, :2])
    assert work[0, 2] == levels.floor_z and work[1, 2] == pytest.approx(levels.floor_z + 2.5)
    assert start_position(scan, 1.2)[2] == pytest.approx(levels.floor_z + 1.2)


def _fly(scene: Path, out: Path, *sets: str) -> list[dict]:
    args = ["fly", "demo", "--quiet", "--no-record", "--out", str(out), "--set", f"scene.path={scene}",
            "--set", "budget.frames=8", "--set", "budget.initial_views=2", "--set", "evaluation.views=3"]
    for s in sets:
        args += ["--set", s]
    p = subprocess.run([sys.executable, "-m", "flightrecon.cli", *args], cwd=ROOT, capture_output=True,
                       text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    with open(out / "frames.csv") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_flight_in_an_open_scan_moves_every_frame(open_scan, tmp_path):
    rows = _fly(open_scan, tmp_path / "run")
    moving = rows[1:-1]  # frame 0 turns in place; the last frame only captures
    assert all(r["recovery"] == "" for r in rows[:-1]), [r["recovery"] for r in rows]
    distance = [float(r["flight_distance"]) for r in moving]
    assert all(b > a for a, b in zip(distance, distance[1:])), distance
    assert int(rows[-2]["contacts"]) == 0


@pytest.mark.slow
def test_a_workspace_without_room_is_said_once_naming_the_keys(open_scan, tmp_path):
    # 1.3 m above the floor, less the drone's clearance, is below the 1.2 m take-off height
    rows = _fly(open_scan, tmp_path / "run", "planner.max_height=1.3")
    assert all(r["recovery"] == "hover" for r in rows[:-1])
    log = (tmp_path / "run" / "events.log").read_text()
    assert log.count("cannot leave its take-off point") == 1
    assert "planner.max_height" in log and "sim.takeoff_height" in log


def test_scene_info_reports_floor_ceiling_and_workspace(open_scan, capsys):
    import json

    from flightrecon.cli import main as cli_main

    assert cli_main(["scene", "info", str(open_scan), "--json", "--max-height", "2.5"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["ceiling_z"] is None and abs(info["floor_z"]) < 0.01
    assert info["workspace_max"][2] == pytest.approx(info["floor_z"] + 2.5, abs=1e-3)
    assert cli_main(["scene", "info", str(open_scan)]) == 0
    assert "ceiling none" in capsys.readouterr().out
