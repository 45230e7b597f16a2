"""Scene loading: round trips for every format on real files, and one SceneError per bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flightrecon.cli import main as cli_main
from flightrecon.errors import SceneError
from flightrecon.scene import load_scene
from flightrecon.scene.builder import QuadMeshBuilder
from flightrecon.scene.patterns import solid
from flightrecon.scene.replica_ply import quads_to_triangles, write_replica_ply
from flightrecon.scene.types import Scene

DATA = Path(__file__).parent / "data"


def _box_scene() -> Scene:
    b = QuadMeshBuilder()
    rng = np.random.default_rng(3)
    b.box([0.2, -0.1, 0.5], [1.0, 0.6, 0.4], lambda s, t: np.stack([s, t, 0.5 + 0 * s], 1), 0.1)
    b.cylinder([1.5, 0, 0], 0.2, 0.1, 0.5, solid([0.2, 0.6, 0.9], rng), 10, 0.1)
    v, c, n, q = b.build()
    return Scene("box", v.astype(np.float64), quads_to_triangles(q), vertex_colors=c,
                 vertex_normals=n.astype(np.float64), meta={"quad_faces": True})


def test_hand_written_quad_ply_has_known_colors_and_splits_quads():
    s = load_scene(DATA / "two_quads_ascii.ply")
    assert s.meta["quad_faces"]
    np.testing.assert_array_equal(s.faces, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    np.testing.assert_array_equal(s.vertex_colors[[0, 2, 5]], [[255, 0, 0], [0, 0, 255], [255, 0, 255]])
    np.testing.assert_allclose(s.bounds, [[0, 0, 0], [2, 1, 0]])
    assert s.appearance == "vertex colors"
    assert s.name == "two_quads_ascii"


def test_replica_binary_round_trip_is_exact(tmp_path):
    scene = _box_scene()
    path = write_replica_ply(scene, tmp_path / "mesh.ply")
    header = path.read_bytes()[:400].split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in header
    assert "property list uchar int vertex_indices" in header and "property float nx" in header
    back = load_scene(path)
    assert back.name == tmp_path.name  # Replica layout: the folder names the scene
    np.testing.assert_array_equal(back.vertices, scene.vertices)
    np.testing.assert_array_equal(back.faces, scene.faces)
    np.testing.assert_array_equal(back.vertex_colors, scene.vertex_colors)
    np.testing.assert_allclose(back.vertex_normals, scene.vertex_normals, atol=1e-7)
    # every stored face is a quad: 1 count byte + 4 int32 per face after the vertex block
    n_bytes = len(path.read_bytes()) - len(header) - len("end_header\n")
    assert n_bytes == len(scene.vertices) * 27 + len(scene.faces) // 2 * 17
    assert load_scene(tmp_path).source == path  # a Replica scene folder is accepted too


def test_triangle_ply_with_vertex_colors(tmp_path):
    import trimesh

    scene = _box_scene()
    colors = np.column_stack([scene.vertex_colors, np.full(len(scene.vertices), 255, np.uint8)])
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, vertex_colors=colors, process=False)
    path = tmp_path / "scan.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
    back = load_scene(path)
    assert not back.meta["quad_faces"]
    np.testing.assert_allclose(back.vertices, scene.vertices, atol=1e-6)
    np.testing.assert_array_equal(back.faces, scene.faces)
    np.testing.assert_array_equal(back.vertex_colors, scene.vertex_colors)


def _write_textured_obj(folder: Path) -> np.ndarray:
    """A unit quad in the x-y plane with a 2x2 texture (red, green / blue, white)."""
    import cv2

    tex = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], np.uint8)  # RGB rows top-down
    cv2.imwrite(str(folder / "tex.png"), cv2.cvtColor(tex, cv2.COLOR_RGB2BGR))
    (folder / "quad.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    (folder / "quad.obj").write_text(
        "mtllib quad.mtl\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl m\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    return tex


def test_obj_with_mtl_texture(tmp_path):
    tex = _write_textured_obj(tmp_path)
    s = load_scene(tmp_path / "quad.obj")
    assert s.appearance == "texture"
    np.testing.assert_array_equal(s.texture, tex)
    # OBJ convention: vt (0, 1) is the top-left of the image
    top_left = np.argmin(np.linalg.norm(s.vertices - [0, 1, 0], axis=1))
    np.testing.assert_allclose(s.uv[top_left], [0, 1])
    assert len(s.faces) == 2


def test_glb_round_trip_with_vertex_colors(tmp_path):
    import trimesh

    scene = _box_scene()
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, vertex_colors=scene.vertex_colors, process=False)
    path = tmp_path / "scene.glb"
    mesh.export(path)
    back = load_scene(path)
    assert back.appearance == "vertex colors"
    assert len(back.faces) == len(scene.faces)
    # the same colored triangles, corner by corner
    np.testing.assert_allclose(back.vertices[back.faces], scene.vertices[scene.faces], atol=1e-6)
    np.testing.assert_array_equal(back.vertex_colors[back.faces], scene.vertex_colors[scene.faces])


def test_y_up_and_unit_scale(tmp_path):
    s = load_scene(DATA / "two_quads_ascii.ply", unit_scale=0.01, up_axis="y")
    # file +y (up) -> world +z, file +z -> world -y; centimeters -> meters
    i = 3  # file vertex (0, 1, 0)
    np.testing.assert_allclose(s.vertices[i], [0, 0, 0.01])
    np.testing.assert_allclose(s.bounds, [[0, 0, 0], [0.02, 0, 0.01]])
    assert s.source_up_axis == "y"


def _expect_scene_error(path, *words):
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    msg = str(exc.value)
    assert str(path) in msg, msg
    for w in words:
        assert w in msg.lower(), msg
    assert "\n" not in msg


def test_missing_file(tmp_path):
    _expect_scene_error(tmp_path / "nope.ply", "not found")


def test_truncated_binary_ply(tmp_path):
    path = write_replica_ply(_box_scene(), tmp_path / "mesh.ply")
    data = path.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) // 2])
    _expect_scene_error(cut, "cannot read")


def test_malformed_ply_header():
    _expect_scene_error(DATA / "malformed_header.ply", "cannot read")


def test_nan_vertex():
    _expect_scene_error(DATA / "nan_vertex_ascii.ply", "nan")


def test_empty_mesh():
    _expect_scene_error(DATA / "no_faces_ascii.ply", "no faces")


def test_face_index_out_of_range():
    _expect_scene_error(DATA / "bad_index_ascii.ply", "index")


def test_garbage_obj_and_glb(tmp_path):
    obj = tmp_path / "junk.obj"
    obj.write_text("this is not an obj file\n")
    _expect_scene_error(obj)
    glb = tmp_path / "junk.glb"
    glb.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    _expect_scene_error(glb, "cannot read")


def test_unsupported_suffix(tmp_path):
    p = tmp_path / "scene.stl"
    p.write_text("solid x\nendsolid x\n")
    _expect_scene_error(p, "unsupported")


def test_cli_reports_bad_scene_in_one_line(tmp_path, capsys):
    code = cli_main(["scene", "info", str(DATA / "nan_vertex_ascii.ply")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "nan_vertex_ascii.ply" in err and "Traceback" not in err
