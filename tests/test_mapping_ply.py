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
COLUMNS = ["means", "quats", "log_scales", "opacity_logits", "colors", "reliability", "frame_created", "n_observed"]


def _map(n: int = 257) -> GaussianMap:
    g = torch.Generator().manual_seed(0)
    gmap = GaussianMap(capacity=8)
    gmap.append(frame=0, means=torch.randn(n, 3, generator=g), quats=torch.randn(n, 4, generator=g),
                log_scales=torch.randn(n, 2, generator=g) - 3, opacity_logits=torch.randn(n, generator=g),
                colors=torch.rand(n, 3, generator=g))
    gmap.add_column("reliability", (2,), torch.float32)  # 2D GauSS-MI's column, which the extras carry
    gmap["reliability"][:] = torch.randn(n, 2, generator=g)
    gmap["frame_created"][:] = torch.arange(n, dtype=torch.int32) // 10
    gmap["n_observed"][:] = torch.arange(n, dtype=torch.int32) % 7
    return gmap


def test_round_trip_with_extras_is_bit_exact(tmp_path):
    gmap = _map()
    path = save_map(gmap, tmp_path / "map.ply", extras=True)
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
    path = save_map(gmap, tmp_path / "map.ply", extras=True)
    v = PlyData.read(str(path))["vertex"]
    names = [p.name for p in v.properties]
    assert names[:16] == TWO_DGS
    assert {"reliability_front", "reliability_back"} <= set(names)
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
