"""map.ply: bit-exact round trip, readable by plyfile and trimesh with the 2DGS properties."""

import numpy as np
import pytest
import torch
import trimesh
from plyfile import PlyData, PlyElement

from flightrecon.errors import DataError
from flightrecon.geometry import quat_to_rotmat
from flightrecon.mapping.ply import SH_C0, load_map, save_map
from flightrecon.mapping.store import GaussianMap

TWO_DGS = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
           "rot_0", "rot_1", "rot_2", "rot_3"]
# selector columns as selectors declare them; "rotation_conf" would be taken for a rotation by 2DGS
# loaders (they collect every property starting with "rot") if it were written under its own name
SELECTOR_COLUMNS = {"reliability": (2,), "ags_S": (), "rotation_conf": (3,)}
COLUMNS = ["means", "quats", "log_scales", "opacity_logits", "colors", "frame_created", "n_observed",
           *SELECTOR_COLUMNS]


def _map(n: int = 257) -> GaussianMap:
    g = torch.Generator().manual_seed(0)
    gmap = GaussianMap(capacity=8)
    gmap.append(frame=0, means=torch.randn(n, 3, generator=g), quats=torch.randn(n, 4, generator=g),
                log_scales=torch.randn(n, 2, generator=g) - 3, opacity_logits=torch.randn(n, generator=g),
                colors=torch.rand(n, 3, generator=g))
    for name, shape in SELECTOR_COLUMNS.items():
        gmap.add_column(name, shape, torch.float32)
        gmap[name][:] = torch.randn(n, *shape, generator=g)
    gmap["frame_created"][:] = torch.arange(n, dtype=torch.int32) // 10
    gmap["n_observed"][:] = torch.arange(n, dtype=torch.int32) % 7
    return gmap


def test_round_trip_with_extras_is_bit_exact(tmp_path):
    gmap = _map()
    path = save_map(gmap, tmp_path / "map.ply", extras=True, columns=SELECTOR_COLUMNS)
    back = load_map(path)
    assert len(back) == len(gmap)
    for name in COLUMNS:
        assert back[name].dtype == gmap[name].dtype
        assert torch.equal(back[name], gmap[name]), name


def test_default_file_holds_the_2dgs_columns_alone(tmp_path):
    gmap = _map()
    path = save_map(gmap, tmp_path / "map.ply")
    v = PlyData.read(str(path))["vertex"]
    assert [p.name for p in v.properties] == TWO_DGS
    header = path.read_bytes().index(b"end_header\n") + len(b"end_header\n")
    assert path.stat().st_size - header == 64 * len(gmap)
    back = load_map(path)
    for name in ("means", "quats", "log_scales", "opacity_logits"):
        assert torch.equal(back[name], gmap[name]), name
    torch.testing.assert_close(back["colors"], gmap["colors"], rtol=0, atol=1e-6)  # through f_dc in float32
    assert "reliability" not in back and torch.all(back["n_observed"] == 0)


def test_file_has_2dgs_layout_and_opens_in_trimesh(tmp_path):
    gmap = _map()
    path = save_map(gmap, tmp_path / "map.ply", extras=True, columns=SELECTOR_COLUMNS)
    v = PlyData.read(str(path))["vertex"]
    names = [p.name for p in v.properties]
    assert names[:16] == TWO_DGS
    assert {"col_reliability_0", "col_reliability_1", "col_ags_S", "col_rotation_conf_2"} <= set(names)
    assert "scale_2" not in names
    q = gmap["quats"].numpy()
    np.testing.assert_allclose(np.stack([v["nx"], v["ny"], v["nz"]], 1), quat_to_rotmat(q)[:, :, 2], atol=1e-6)
    np.testing.assert_allclose(v["f_dc_1"] * SH_C0 + 0.5, gmap["colors"][:, 1].numpy(), atol=1e-6)
    cloud = trimesh.load(path)
    np.testing.assert_array_equal(np.asarray(cloud.vertices, np.float32), gmap["means"].numpy())


def test_3dgs_export_adds_a_flat_third_scale(tmp_path):
    path = save_map(_map(), tmp_path / "map3d.ply", for_3dgs=True)
    v = PlyData.read(str(path))["vertex"]
    assert np.all(v["scale_2"] == np.float32(np.log(1e-6)))
    assert torch.equal(load_map(path)["log_scales"], _map()["log_scales"])


def test_plain_2dgs_file_loads_colors_from_sh(tmp_path):
    n = 5
    arr = np.zeros(n, dtype=[(p, "<f4") for p in TWO_DGS])
    arr["rot_0"] = 1.0
    arr["f_dc_2"] = (0.8 - 0.5) / SH_C0
    path = tmp_path / "other.ply"
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(path))
    gmap = load_map(path)
    np.testing.assert_allclose(gmap["colors"][:, 2].numpy(), 0.8, atol=1e-6)
    assert "reliability" not in gmap


def _reference_2dgs_read(path, sh_degree: int) -> dict:
    """What the reference 2DGS loader (GaussianModel.load_ply of its public code) takes from a file, by
    its documented rules: x y z, opacity, f_dc_0..2, every property starting with f_rest_ (exactly
    3 (d+1)^2 - 3 of them), with scale_ (first two kept) and with rot, each sorted by trailing number."""
    v = PlyData.read(str(path))["vertex"]
    names = [p.name for p in v.properties]
    def starting(prefix):
        return sorted((n for n in names if n.startswith(prefix)), key=lambda n: int(n.split("_")[-1]))
    rest = starting("f_rest_")
    if len(rest) != 3 * (sh_degree + 1) ** 2 - 3:
        raise AssertionError(f"{len(rest)} f_rest properties for SH degree {sh_degree}")
    return {"xyz": np.stack([v["x"], v["y"], v["z"]], 1), "opacity": np.asarray(v["opacity"]),
            "f_dc": np.stack([v[f"f_dc_{i}"] for i in range(3)], 1),
            "scales": np.stack([v[n] for n in starting("scale_")], 1)[:, :2],
            "rots": np.stack([v[n] for n in starting("rot")], 1)}


@pytest.mark.parametrize("extras", [False, True])
def test_reference_2dgs_loader_reads_the_file_at_sh_degree_0(tmp_path, extras):
    gmap = _map()
    path = save_map(gmap, tmp_path / "map.ply", extras=extras, columns=SELECTOR_COLUMNS)
    got = _reference_2dgs_read(path, sh_degree=0)
    np.testing.assert_array_equal(got["xyz"], gmap["means"].numpy())
    np.testing.assert_array_equal(got["scales"], gmap["log_scales"].numpy())
    np.testing.assert_array_equal(got["rots"], gmap["quats"].numpy())  # four, selector columns not among them
    np.testing.assert_array_equal(got["opacity"], gmap["opacity_logits"].numpy())
    np.testing.assert_allclose(got["f_dc"] * SH_C0 + 0.5, gmap["colors"].numpy(), atol=1e-6)
    with pytest.raises(AssertionError, match="0 f_rest properties for SH degree 3"):
        _reference_2dgs_read(path, sh_degree=3)  # its default degree needs --sh_degree 0 (docs/outputs.md)


def test_bad_files_raise_data_error_naming_the_file(tmp_path):
    with pytest.raises(DataError, match="missing.ply"):
        load_map(tmp_path / "missing.ply")
    bad = tmp_path / "torn.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n")
    with pytest.raises(DataError, match="torn.ply"):
        load_map(bad)
    arr = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    cloud = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(cloud))
    with pytest.raises(DataError, match="lacks the 2DGS properties"):
        load_map(cloud)
