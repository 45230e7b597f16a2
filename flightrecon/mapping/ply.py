"""`map.ply`: the map in the 2DGS point-cloud layout, plus our own per-splat properties.

What common 2DGS tools read, and by default nothing else (64 bytes a splat): x y z, nx ny nz,
f_dc_0..2 (SH degree-0 coefficients, (color - 0.5) / C0), opacity (logit), scale_0 scale_1 (log),
rot_0..3 (quaternion w x y z). We write nx ny nz as the splat normal (2DGS writes zeros; tools
ignore them). Colors are view-independent, so there are no f_rest_* properties: the reference 2DGS
loader reads the file as a model of SH degree 0 (`GaussianModel(sh_degree=0)`, `--sh_degree 0`);
at its default degree 3 it asserts 45 f_rest_* properties (docs/outputs.md).

`extras=True` (output.ply_extras) adds our own per-splat properties: color_0..2 (the raw colors,
because f_dc in float32 does not convert back bit-exactly), frame_created, n_observed, and the map
columns the selector declared (`columns`), each as col_<name> or col_<name>_<i>; a header comment
`flightrecon column <name> <shape>` per column lets `load_map` restore them. The col_ prefix keeps
them clear of the prefixes 2DGS and 3DGS loaders collect (scale_, rot, f_rest_). `for_3dgs=True`
adds scale_2 = log(1e-6) so 3DGS viewers, which expect three scales, show the splats as flat disks.
Written atomically; `load_map` gives back exactly what `save_map` was given with extras, and without
them the parameters with colors to float rounding (from f_dc) and zero bookkeeping.
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

COLUMN_COMMENT = "flightrecon column"
# PLY property -> (map column, component index or None for scalars)
_LAYOUT: list[tuple[str, str, int | None]] = (
    [(f"{a}", "means", i) for i, a in enumerate("xyz")]
    + [(f"scale_{i}", "log_scales", i) for i in range(2)]
    + [(f"rot_{i}", "quats", i) for i in range(4)]
    + [("opacity", "opacity_logits", None)]
    + [(f"color_{i}", "colors", i) for i in range(3)]
    + [("frame_created", "frame_created", None), ("n_observed", "n_observed", None)]
)


def save_map(gmap: GaussianMap, path: str | Path, for_3dgs: bool = False, extras: bool = False,
             columns: dict[str, tuple[int, ...]] | None = None) -> Path:
    """Write the map as a binary little-endian PLY (atomic); `extras` adds our own properties and the
    selector's `columns` (name -> per-splat shape) that the map holds."""
    n = len(gmap)
    cols = {name: gmap[name].detach().cpu().numpy() for name in list(PARAM_SHAPES) + list(META_SHAPES)}
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
        fields += [("frame_created", cols["frame_created"]), ("n_observed", cols["n_observed"])]
    comments = []
    for name, shape in (columns or {}).items() if extras else ():
        if name not in gmap:
            continue
        flat = gmap[name].detach().cpu().numpy().astype(np.float32).reshape(n, -1)
        props = [f"col_{name}"] if not tuple(shape) else [f"col_{name}_{i}" for i in range(flat.shape[1])]
        fields += [(prop, flat[:, i]) for i, prop in enumerate(props)]
        comments.append(f"{COLUMN_COMMENT} {name} {','.join(map(str, shape)) or 'scalar'}")
    arr = np.empty(n, dtype=[(name, v.dtype.newbyteorder("<")) for name, v in fields])
    for name, v in fields:
        arr[name] = v
    path = Path(path)
    with fileio.atomic_path(path) as tmp:
        PlyData([PlyElement.describe(arr, "vertex")], text=False, byte_order="<",
                comments=comments).write(str(tmp))
    return path


def _declared_columns(comments: list[str]) -> dict[str, tuple[int, ...]]:
    """Selector columns named in the header comments: name -> per-splat shape."""
    out = {}
    for c in comments:
        if c.startswith(COLUMN_COMMENT + " "):
            name, shape = c[len(COLUMN_COMMENT) + 1:].split()
            out[name] = () if shape == "scalar" else tuple(int(k) for k in shape.split(","))
    return out


def load_map(path: str | Path, device: str | torch.device = "cpu") -> GaussianMap:
    """Read a map written by `save_map`; a 2DGS file without our extras gets colors from f_dc."""
    path = Path(path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
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
    for name, shape in _declared_columns(ply.comments).items():
        props = [f"col_{name}"] if not shape else [f"col_{name}_{i}" for i in range(int(np.prod(shape)))]
        if not set(props) <= names:
            raise DataError(f"map file {path} names column {name!r} in its header but lacks {props[0]}..")
        cols[name] = np.stack([v[p] for p in props], axis=1).reshape(n, *shape).astype(np.float32)
    gmap = GaussianMap(capacity=max(n, 1), device=device)
    for name in set(cols) - set(PARAM_SHAPES) - set(META_SHAPES):
        gmap.add_column(name, cols[name].shape[1:], torch.float32)
    frame = cols.pop("frame_created", np.zeros(n, np.int32))
    gmap.append(frame=0, **{k: torch.from_numpy(np.ascontiguousarray(a)) for k, a in cols.items()})
    gmap["frame_created"][:] = torch.from_numpy(np.ascontiguousarray(frame))
    return gmap


def _column_spec(col: str) -> tuple[tuple[int, ...], np.dtype]:
    if col in PARAM_SHAPES:
        return PARAM_SHAPES[col], np.dtype(np.float32)
    shape, dtype = META_SHAPES[col]
    return shape, np.dtype(str(dtype).removeprefix("torch."))
