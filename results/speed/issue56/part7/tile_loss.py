"""Could an iteration skip the tiles whose loss has converged? How the color error of a frame is spread
over the rasterizer's 16x16 tiles: the share of the frame's color L1 that its highest-error quarter
and half of the tiles hold, for each of the first N frames of a survey mapped with the CPU default's
mapper, at three moments: the new frame before its update (what its first K_new iterations see),
the same frame after it, and an earlier frame drawn at random (what a replay iteration sees). If half
the tiles held nearly all of the error, an iteration could skip the other half at little cost.

    python results/speed/issue56/part7/tile_loss.py SURVEY N out.json   # record (minutes)
    python results/speed/issue56/part7/tile_loss.py --summary out.json  # the table in README.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

TILE = 16  # the rasterizer's tile size (csrc/rasterize.h, TS)
SHARES = (0.25, 0.5)


def top_tile_shares(error: np.ndarray) -> list[float]:
    """The share of the summed per-pixel `error` [H,W] held by the highest-error SHARES of the whole
    TILE x TILE tiles."""
    H, W = (n // TILE * TILE for n in error.shape)
    tiles = error[:H, :W].reshape(H // TILE, TILE, W // TILE, TILE).sum((1, 3)).ravel()
    ranked = np.sort(tiles)[::-1]
    return [float(ranked[:int(round(len(ranked) * q))].sum() / ranked.sum()) for q in SHARES]


def record(survey: str, frames: int, out: str) -> None:
    from flightrecon import provenance
    from flightrecon.dataset import load_dataset
    from flightrecon.mapping.mapper import OnlineMapper
    from flightrecon.scenario import load_config

    cfg = load_config("default")
    mapper = OnlineMapper(cfg.mapper, near=cfg.camera.near, far=cfg.camera.far, seed=0, device="cpu")
    data = load_dataset(survey)
    rng = np.random.default_rng(0)

    def shares(f) -> list[float]:
        rendered = mapper.render_view(f.T_wc, f.K, f.rgb.shape[1], f.rgb.shape[0], outputs=("features",))
        color = rendered.features[0].clamp(0, 1).cpu().numpy()
        return top_tile_shares(np.abs(color - f.rgb[..., :3]).mean(-1))

    rows = []
    for i in range(frames):
        f = data[i]
        before = shares(f) if i > 0 else None  # an empty map explains nothing: every tile is all error
        mapper.add_frame(f.rgb, f.depth, f.K, f.T_wc)
        rows.append({"frame": i, "new_before": before, "new_after": shares(f),
                     "earlier": shares(data[int(rng.integers(i + 1))])})
    with open(out, "w") as fh:
        json.dump({"survey": Path(survey).name, "provenance": provenance.stamp(), "rows": rows}, fh, indent=1)


def summary(path: str) -> None:
    rows = json.load(open(path))["rows"]
    print("| moment | highest quarter of the tiles (median, range) | highest half |\n|---|---|---|")
    for key, name in (("new_before", "new frame, before its update"), ("new_after", "new frame, after it"),
                      ("earlier", "an earlier frame (replay)")):
        v = np.array([r[key] for r in rows if r[key] is not None])
        cells = [f"{np.median(v[:, k]):.2f} ({v[:, k].min():.2f}-{v[:, k].max():.2f})" for k in range(len(SHARES))]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    if sys.argv[1] == "--summary":
        summary(sys.argv[2])
    else:
        record(sys.argv[1], int(sys.argv[2]), sys.argv[3])
