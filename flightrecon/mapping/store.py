"""The Gaussian map: a struct of per-splat arrays that grows by capacity doubling.

Every per-splat quantity (splat parameters, bookkeeping, and the optimizer's moments, which register
themselves as columns) lives in one capacity-sized buffer per name, so appending a frame's splats
copies only the new rows (the whole map is copied only when the capacity doubles) and pruning
compacts every column with the same mask: the optimizer state can never fall out of step.
"""

from __future__ import annotations

import torch

from flightrecon.errors import DataError

# Trainable splat parameters (docs/architecture.md, "The map"): name -> trailing shape.
PARAM_SHAPES: dict[str, tuple[int, ...]] = {
    "means": (3,),
    "quats": (4,),  # (w, x, y, z), not necessarily normalized
    "log_scales": (2,),
    "opacity_logits": (),
    "colors": (3,),  # linear RGB, view-independent (no spherical harmonics, as in the paper)
}
# Bookkeeping columns: name -> (trailing shape, dtype). Selectors add their own columns (add_column).
META_SHAPES: dict[str, tuple[tuple[int, ...], torch.dtype]] = {
    "frame_created": ((), torch.int32),
    "n_observed": ((), torch.int32),  # frames in which the splat was visible during its own update
}


class GaussianMap:
    """Struct of arrays over `len(self)` splats; `self[name]` is a view of the live rows."""

    def __init__(self, capacity: int = 1024, device: str | torch.device = "cpu") -> None:
        self.device = torch.device(device)
        self._n = 0
        self._cap = max(1, int(capacity))
        self._cols: dict[str, torch.Tensor] = {}
        for name, shape in PARAM_SHAPES.items():
            self.add_column(name, shape, torch.float32)
        for name, (shape, dtype) in META_SHAPES.items():
            self.add_column(name, shape, dtype)

    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        return self._cap

    def __getitem__(self, name: str) -> torch.Tensor:
        return self._cols[name][: self._n]

    def __contains__(self, name: str) -> bool:
        return name in self._cols

    def check_finite(self) -> None:
        """Raise a DataError naming the first float column that holds NaN or inf, and where."""
        for name, col in self._cols.items():
            live = col[: self._n]
            if live.is_floating_point() and not bool(torch.isfinite(live.sum())) and not bool(torch.isfinite(live).all()):
                bad = ~torch.isfinite(live).reshape(self._n, -1).all(dim=1)
                raise DataError(f"map column {name!r} holds NaN or inf at {int(bad.sum())} of {self._n} splats "
                                f"(first: splat {int(bad.nonzero()[0, 0])})")

    def add_column(self, name: str, shape: tuple[int, ...], dtype: torch.dtype, fill: float = 0.0) -> None:
        """Register a per-splat array (e.g. an optimizer moment); existing rows get `fill`."""
        if name in self._cols:
            raise ValueError(f"column {name!r} already exists")
        self._cols[name] = torch.full((self._cap, *shape), fill, dtype=dtype, device=self.device)

    def append(self, frame: int = 0, **values: torch.Tensor) -> slice:
        """Add rows; every parameter of PARAM_SHAPES must be given, other columns default to zero."""
        missing = set(PARAM_SHAPES) - set(values)
        if missing:
            raise ValueError(f"append needs {sorted(missing)}")
        m = int(values["means"].shape[0])
        self._reserve(self._n + m)
        rows = slice(self._n, self._n + m)
        for name, col in self._cols.items():
            if name in values:
                col[rows] = values[name].to(col.dtype)
            else:
                col[rows] = 0
        self._cols["frame_created"][rows] = frame
        self._n += m
        return rows

    def keep(self, mask: torch.Tensor) -> None:
        """Drop the rows where `mask` (len(self),) is False, in every column at once."""
        idx = torch.nonzero(mask, as_tuple=True)[0]
        k = int(idx.shape[0])
        for col in self._cols.values():
            col[:k] = col[idx]
        self._n = k

    def _reserve(self, n: int) -> None:
        if n <= self._cap:
            return
        cap = self._cap
        while cap < n:
            cap *= 2
        for name, col in self._cols.items():
            new = torch.zeros((cap, *col.shape[1:]), dtype=col.dtype, device=col.device)
            new[: self._n] = col[: self._n]
            self._cols[name] = new
        self._cap = cap

    def get_state(self) -> dict:
        """The live rows of every column (selectors' and the optimizer's too), as CPU copies: a
        snapshot for flightrecon.checkpoint that later changes to the map do not reach."""
        return {"columns": {name: col[: self._n].detach().to("cpu", copy=True) for name, col in self._cols.items()}}

    def set_state(self, state: dict) -> None:
        """Replace every column by those of a `get_state()` snapshot, on this map's device."""
        cols = state["columns"]
        n = int(next(iter(cols.values())).shape[0])
        cap = max(self._cap, n)
        self._cols = {}
        for name, values in cols.items():
            col = torch.zeros((cap, *values.shape[1:]), dtype=values.dtype, device=self.device)
            col[:n] = values
            self._cols[name] = col
        self._n, self._cap = n, cap

    def nbytes(self) -> int:
        """Bytes of the live rows of the splat parameters and bookkeeping (not optimizer state)."""
        names = list(PARAM_SHAPES) + list(META_SHAPES)
        return sum(self[n].element_size() * self[n].numel() for n in names)
