"""The public datasets' own file conventions load without flags (README, "Real scans"): a small
fixture per dataset, written here by hand in that dataset's exact layout (header, property names,
face type, axis convention), holds the loader to it.

- Replica `mesh.ply`: binary little-endian PLY, float x y z nx ny nz, uchar red green blue, quad
  faces (`list uchar int vertex_indices`), z up, metres.
- ScanNet `sceneXXXX_XX_vh_clean_2.ply`: binary little-endian PLY, float x y z, uchar red green blue
  alpha, triangle faces, z up, metres.
- Matterport3D / HM3D `.glb`: glTF binary, textured, y up (glTF's convention), metres.
- ICL-NUIM `living-room.obj`: OBJ + MTL + texture image with v/vt/vn faces, stored with -y up,
  metres.

Each is the same furnished room (room0, coarse cells), so what must come back is known: its
heights (floor at 0, ceiling, furniture) along world z, and its footprint.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from flightrecon.errors import SceneError
from flightrecon.scenario import load_config
from flightrecon.scene.levels import scene_levels
from flightrecon.scene.source import scene_from_config
from flightrecon.scene.types import Scene
from mesh_scenes import coarse_room

# file coordinates = R @ world (z up): y up maps world z to file +y, -y up maps it to file -y
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
MINUS_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@pytest.fixture(scope="module")
def room() -> Scene:
    return coarse_room()


def _ply_header(n_vertices: int, vertex_props: list[tuple[str, str]], n_faces: int) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {n_vertices}"]
    lines += [f"property {t} {name}" for name, t in vertex_props]
    lines += [f"element face {n_faces}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(lines) + "\n").encode()


def _faces_bytes(faces: np.ndarray) -> bytes:
    k = faces.shape[1]
    rec = np.zeros(len(faces), np.dtype([("n", "u1"), ("idx", "<i4", (k,))]))
    rec["n"], rec["idx"] = k, faces
    return rec.tobytes()


def _colors8(room: Scene) -> np.ndarray:
    return np.clip(np.round(room.vertex_colors * 255), 0, 255).astype(np.uint8)


def write_replica(room: Scene, folder: Path) -> Path:
    props = [(a, "float") for a in ("x", "y", "z", "nx", "ny", "nz")] + [(c, "uchar") for c in ("red", "green", "blue")]
    v = np.zeros(len(room.vertices), np.dtype([(a, "<f4") for a in ("x", "y", "z", "nx", "ny", "nz")]
                                              + [(c, "u1") for c in ("red", "green", "blue")]))
    for i, a in enumerate("xyz"):
        v[a], v["n" + a] = room.vertices[:, i], room.vertex_normals[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        v[c] = _colors8(room)[:, i]
    halves = room.faces.reshape(-1, 2, 3)  # the generator's quads, as consecutive triangle pairs
    quads = np.concatenate([halves[:, 0], halves[:, 1, 2:3]], axis=1)
    folder.mkdir(parents=True)
    path = folder / "mesh.ply"
    path.write_bytes(_ply_header(len(v), props, len(quads)) + v.tobytes() + _faces_bytes(quads))
    return folder  # Replica's layout: a scene folder holding mesh.ply


def write_scannet(room: Scene, folder: Path) -> Path:
    props = [(a, "float") for a in "xyz"] + [(c, "uchar") for c in ("red", "green", "blue", "alpha")]
    v = np.zeros(len(room.vertices), np.dtype([(a, "<f4") for a in "xyz"]
                                              + [(c, "u1") for c in ("red", "green", "blue", "alpha")]))
    for i, a in enumerate("xyz"):
        v[a] = room.vertices[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        v[c] = _colors8(room)[:, i]
    v["alpha"] = 255
    folder.mkdir(parents=True)
    path = folder / "scene0000_00_vh_clean_2.ply"
    path.write_bytes(_ply_header(len(v), props, len(room.faces)) + v.tobytes() + _faces_bytes(room.faces))
    return path


def _atlas(room: Scene) -> tuple[np.ndarray, np.ndarray]:
    """A texture holding each vertex's color in one texel, and the UV of that texel per vertex."""
    n = len(room.vertices)
    side = int(np.ceil(np.sqrt(n)))
    img = np.zeros((side, side, 3), np.uint8)
    rows, cols = np.divmod(np.arange(n), side)
    img[rows, cols] = _colors8(room)
    uv = np.stack([(cols + 0.5) / side, 1.0 - (rows + 0.5) / side], axis=1)  # v = 0 at the image bottom
    return img, uv


def write_matterport(room: Scene, folder: Path) -> Path:
    import trimesh

    img, uv = _atlas(room)
    mesh = trimesh.Trimesh(room.vertices @ Y_UP.T, room.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(img)))
    folder.mkdir(parents=True)
    path = folder / "17DRP5sb8fy.glb"
    mesh.export(path)
    return path


def write_icl(room: Scene, folder: Path) -> Path:
    img, uv = _atlas(room)
    folder.mkdir(parents=True)
    Image.fromarray(img).save(folder / "living-room.png")
    (folder / "living-room.mtl").write_text("newmtl room\nKa 1 1 1\nKd 1 1 1\nmap_Kd living-room.png\n")
    v = room.vertices @ MINUS_Y_UP.T
    n = room.vertex_normals @ MINUS_Y_UP.T
    lines = ["# ICL-NUIM style: -y up, metres", "mtllib living-room.mtl"]
    lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in uv]
    lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in n]
    lines.append("usemtl room")
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in f) for f in room.faces]
    path = folder / "living-room.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


WRITERS = {"replica": write_replica, "scannet": write_scannet, "matterport": write_matterport, "icl_nuim": write_icl}


@pytest.mark.parametrize("dataset", list(WRITERS))
def test_each_dataset_convention_loads_level_without_flags(room, tmp_path, dataset):
    path = WRITERS[dataset](room, tmp_path / dataset)
    scene = scene_from_config(load_config(None, [f"scene.path={path}"]).scene)  # every scene key at its default
    est = scene.meta["up_axis"]["estimate"]
    assert est["confidence"] == "confident", est
    # the room comes back with world z up: the same heights, floor and ceiling as the generator's
    np.testing.assert_allclose(np.sort(scene.vertices[:, 2]), np.sort(room.vertices[:, 2]), atol=1e-5)
    levels, truth = scene_levels(scene), scene_levels(room)
    assert levels.floor_z == pytest.approx(truth.floor_z, abs=0.01)  # found in the geometry: within a cm
    assert levels.ceiling_z == pytest.approx(truth.ceiling_z, abs=0.01)
    size = np.sort(np.ptp(scene.vertices[:, :2], axis=0))
    np.testing.assert_allclose(size, np.sort(np.ptp(room.vertices[:, :2], axis=0)), atol=1e-5)
    expected_appearance = "texture" if dataset in ("matterport", "icl_nuim") else "vertex colors"
    assert scene.appearance == expected_appearance


def test_a_floor_whose_faces_average_a_rounding_error_below_it_is_found():
    """(-0.1 * 3) / 3 < -0.1 in floating point: such a face is still in the floor's layer."""
    from flightrecon.scene.levels import _levels_from_geometry

    v = np.array([[0, 0, -0.1], [4, 0, -0.1], [0, 4, -0.1], [0, 0, 2.5], [4, 0, 2.5], [0, 4, 2.5]])
    assert v[:3, 2].mean() < -0.1
    levels = _levels_from_geometry(v, np.array([[0, 1, 2], [3, 5, 4]]))
    assert levels.floor_z == pytest.approx(-0.1) and levels.ceiling_z == pytest.approx(2.5)


def test_a_scan_in_millimetres_is_refused_with_the_scale_that_fits(room, tmp_path):
    path = write_scannet(Scene(room.name, room.vertices * 1000.0, room.faces, vertex_colors=room.vertex_colors),
                         tmp_path / "mm")
    height_m = float(np.ptp(room.vertices, axis=0).min())  # room0's smallest side: its height
    with pytest.raises(SceneError, match=rf"scene {path} spans \d+ m .*likely in another unit; with "
                                         rf"scene.unit_scale = 0.001 its smallest side is {height_m:.2f} m"):
        scene_from_config(load_config(None, [f"scene.path={path}"]).scene)
    scene = scene_from_config(load_config(None, [f"scene.path={path}", "scene.unit_scale=0.001"]).scene)
    np.testing.assert_allclose(np.sort(scene.vertices[:, 2]), np.sort(room.vertices[:, 2]), atol=1e-5)
