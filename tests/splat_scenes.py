"""Tiny splat scenes the tests share (imported by name: pytest puts tests/ on the path, whether run
as `pytest` or `python -m pytest`)."""

import math

import numpy as np
import torch

from flightrecon.geometry import rotmat_to_quat


def wall(n_side: int = 3, x: float = 2.0) -> dict[str, torch.Tensor]:
    """A small wall of splats in the plane x = `x`, normals along -x (facing a camera at the origin)."""
    ys, zs = np.meshgrid(np.linspace(-0.3, 0.3, n_side), np.linspace(0.9, 1.5, n_side))
    means = np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], 1)
    R = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns t_u, t_v, n
    quats = np.repeat(rotmat_to_quat(R)[None], len(means), 0)
    t = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    return {"means": t(means), "quats": t(quats), "log_scales": torch.full((len(means), 2), math.log(0.12)),
            "opacity_logits": torch.full((len(means),), 2.0), "colors": torch.full((len(means), 3), 0.5)}
