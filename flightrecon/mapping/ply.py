"""`map.ply`: the map in the 2DGS point-cloud layout, plus our own per-splat properties.

What common 2DGS tools read, and by default nothing else (64 bytes a splat): x y z, nx ny nz,
f_dc_0..2 (SH degree-0 coefficients, (color - 0.5) / C0), opacity (logit), scale_0 scale_1 (log),
rot_0..3 (quaternion w x y z). We write nx ny nz as the splat normal (2DGS writes zeros; tools
ignore them). `extras=True` (output.ply_extras) adds our own per-splat properties: color_0..2
(the raw colors, because f_dc in float32 does not convert back bit-exactly), reliability_front,
reliability_back, frame_created, n_observed. `for_3dgs=True` adds scale_2 = log(1e-6) so 3DGS
viewers, which expect three scales, show the splats as flat disks. Written atomically; `load_map`
gives back exactly what `save_map` was given with extras, and without them the parameters with
colors to float rounding (from f_dc) and zero reliability and bookkeeping.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from flightrecon import fileio
from flightrecon.errors import DataError
from flightrecon.geometry import quat_to_rotmat
from flightrecon.mapping.store import META_SHAPES, PARAM_SHAPES, GaussianMap

SH_C0 = 0.28209479177387814
FLAT_LOG_SCALE = float(np.log(1e-6))

# The 2D GauSS-MI selector's column, which the extras carry when the map has it (zeros otherwise).
RELIABILITY = "reliability"
# PLY property -> (map column, component index or None for scalars)
_LAYOUT: list[tuple[str, str, int | None]] = (
    [(f"{a}", "means", i) for i, a in enumerate("xyz")]
    + [(f"scale_{i}", "log_scales", i) for i in range(2)]
    + [(f"rot_{i}", "quats", i) for i in range(4)]
    + [("opacity", "opacity_logits", None)]
    + [(f"color_{i}", "colors", i) for i in range(3)]
    + [("reliability_front", "reliability", 0), ("reliability_back", "reliability", 1)]
    + [("frame_created", "frame_created", None), ("n_observed", "n_observed", None)]
)


def save_map(gmap: GaussianMap, path: str | Path, for_3dgs: bool = False, extras: bool = False) -> Path:
    """Write the map as a binary little-endian PLY (atomic); `extras` adds our own columns."""
    n = len(gmap)
    cols = {name: gmap[name].detach().cpu().numpy() for name in list(PARAM_SHAPES) + list(META_SHAPES)}
    cols[RELIABILITY] = (gmap[RELIABILITY].detach().cpu().numpy() if RELIABILITY in gmap
                         else np.zeros((n, 2), np.float32))
    normals = quat_to_rotmat(cols["quats"].astype(np.float64))[..., :, 2] if n else np.zeros((0, 3))
    f_dc = (cols["colors"].astype(np.float64) - 0.5) / SH_C0
    fields: list[tuple[str, np.ndarray]] = [(a, cols["means"][:, i]) for i, a in enumerate("xyz")]
    fields += [(f"n{a}", normals[:, i].astype(np.float32)) for i, a in enumerate("xyz")]
    fields += [(f"f_dc_{i}", f_dc[:, i].astype(np.float32)) for i in range(3)]
    fields += [("opacity", cols["opacity_logits"])]
    fields += [(f"scale_{i}", cols["log_scales"][:, i]) for i in range(2)]
    if for_3dgs:
        fields += [("scale_2", np.full(n, FLAT_LOG_SCALE, np.float32))]
    fields += [(f"rot_{i}", cols["quats"][:, i]) for i in range(4)]
    if extras:
        fields += [(f"color_{i}", cols["colors"][:, i]) for i in range(3)]
        fields += [("reliability_front", cols["reliability"][:, 0]), ("reliability_back", cols["reliability"][:, 1])]
        fields += [("frame_created", cols["frame_created"]), ("n_observed", cols["n_observed"])]
    arr = np.empty(n, dtype=[(name, v.dtype.newbyteorder("<")) for name, v in fields])
    for name, v in fields:
        arr[name] = v
    path = Path(path)
    with fileio.atomic_path(path) as tmp:
        PlyData([PlyElement.describe(arr, "vertex")], text=False, byte_order="<").write(str(tmp))
    return path


def load_map(path: str | Path, device: str | torch.device = "cpu") -> GaussianMap:
    """Read a map written by `save_map`; a 2DGS file without our extras gets colors from f_dc."""
    path = Path(path)
    try:
        v = PlyData.read(str(path))["vertex"].data
    except FileNotFoundError:
        raise DataError(f"map file {path} not found") from None
    except Exception as exc:  # plyfile raises several types for a malformed file
        raise DataError(f"map file {path} is not a readable PLY with a vertex element: {exc}") from None
    names = set(v.dtype.names or ())
    needed = {"x", "y", "z", "opacity", "scale_0", "scale_1", "rot_0", "rot_1", "rot_2", "rot_3"}
    if not {"color_0", "color_1", "color_2"} <= names:
        needed |= {"f_dc_0", "f_dc_1", "f_dc_2"}
    missing = sorted(needed - names)
    if missing:
        raise DataError(f"map file {path} lacks the 2DGS properties {', '.join(missing)}")
    n = len(v)
    cols: dict[str, np.ndarray] = {}
    for prop, col, i in _LAYOUT:
        if prop not in names:
            continue
        shape, dtype = _column_spec(col)
        arr = cols.setdefault(col, np.zeros((n, *shape), dtype=dtype))
        if i is None:
            arr[:] = v[prop]
        else:
            arr[:, i] = v[prop]
    if "colors" not in cols or not {"color_0", "color_1", "color_2"} <= names:
        cols["colors"] = np.stack([v[f"f_dc_{i}"].astype(np.float64) * SH_C0 + 0.5 for i in range(3)],
                                  axis=1).astype(np.float32)
    for name, arr in cols.items():
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise DataError(f"map file {path} holds NaN or inf in {name}")
    gmap = GaussianMap(capacity=max(n, 1), device=device)
    if RELIABILITY in cols:
        gmap.add_column(RELIABILITY, (2,), torch.float32)
    frame = cols.pop("frame_created", np.zeros(n, np.int32))
    gmap.append(frame=0, **{k: torch.from_numpy(np.ascontiguousarray(a)) for k, a in cols.items()})
    gmap["frame_created"][:] = torch.from_numpy(np.ascontiguousarray(frame))
    return gmap


def _column_spec(col: str) -> tuple[tuple[int, ...], np.dtype]:
    if col in PARAM_SHAPES:
        return PARAM_SHAPES[col], np.dtype(np.float32)
    if col == RELIABILITY:
        return (2,), np.dtype(np.float32)
    shape, dtype = META_SHAPES[col]
    return shape, np.dtype(str(dtype).removeprefix("torch."))
