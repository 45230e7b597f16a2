#!/usr/bin/env python3
"""Trace the GauSS-MI baseline's reliabilities through a short flight: per frame the share of its
(splat, direction) log-odds below 0, at or below -5 and above 0, the share of pixels with negative
evidence (lambda_L L > 1) in the frame's loss image, the chosen view's score, and the largest
per-pixel value of the chosen view's gain image. With `--images`, also the evidence image of each
frame (red: negative) as a PNG.

`python tools/gaussmi_trace.py OUT.csv [--scenario sweep_cpu] [--frames 8] [--set KEY=VALUE ...]`

It flies the `gaussmi` selector through a traced subclass registered as `gaussmi_traced`; the code
it traces is whatever `flightrecon` imports (a worktree at an older commit traces that commit).
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np
import torch

from flightrecon.active import baselines
from flightrecon.active.candidate_views import render_candidates
from flightrecon.active.protocol import capture_view, float_tensor
from flightrecon.active.registry import register
from flightrecon.mission import Mission
from flightrecon.scenario import load_config


class TracedGaussMI(baselines.GaussMISelector):
    """GauSS-MI with a row of statistics per observed frame (`rows`)."""

    name = "gaussmi_traced"
    COLUMN = baselines.GaussMISelector.COLUMN

    def __init__(self, cfg, image_dir: Path | None = None) -> None:
        super().__init__(cfg)
        self.rows: list[dict] = []
        self.image_dir = image_dir

    def observe(self, view, obs):
        row = {"frame": obs.index}
        if len(view):
            out = capture_view(view, obs).output
            with torch.no_grad():
                rgb = float_tensor(obs.rgb, view.device)
                d_obs = float_tensor(obs.depth, view.device)[..., None]
                depth = out.depth[0] * out.alpha[0] if out.alpha is not None else out.depth[0]
                L = baselines.gaussmi_loss_image(out.features[0].detach(), depth.detach(), rgb, d_obs)
            negative = (self.cfg.gaussmi.lambda_L * L > 1).numpy()
            row["negative_evidence_pixels"] = float(negative.mean())
            if self.image_dir is not None:
                _save_evidence(self.image_dir / f"evidence_{obs.index:03d}.png", negative)
        diag = super().observe(view, obs)
        l = view.column(self.COLUMN)
        row.update({"n_splats": len(l), "logodds_below_0": float((l < 0).float().mean()),
                    "logodds_at_or_below_-5": float((l <= -5).float().mean()),
                    "logodds_above_0": float((l > 0).float().mean()), "updated": diag.get("updated", 0)})
        self.rows.append(row)
        return diag

    def score(self, view, poses, lengths=None):
        scores = super().score(view, poses, lengths)
        best = int(np.argmax(scores))
        sp = view.splats()
        logodds = view.column(self.COLUMN)
        T = float_tensor(poses[best:best + 1], view.device)
        gain = baselines.gaussmi_gain(logodds, baselines.direction_weights(sp["means"], T[:, :3, 3]))[..., None]
        with torch.no_grad():
            _, out = next(render_candidates(sp, gain, T, self.K_score, self.width, self.height, near=view.near,
                                            far=view.far, backend=self.cfg.mapper.backend))
        self.rows[-1].update({"chosen_score": float(scores[best]), "pixels": self.width * self.height,
                              "max_pixel_score": float(out.features.max())})
        return scores


def _save_evidence(path: Path, negative: np.ndarray) -> None:
    from PIL import Image

    img = np.full(negative.shape + (3,), 230, np.uint8)
    img[negative] = (220, 30, 30)
    Image.fromarray(img).resize((negative.shape[1] * 2, negative.shape[0] * 2), Image.NEAREST).save(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="CSV to write")
    ap.add_argument("--scenario", default="sweep_cpu")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--images", action="store_true", help="also write evidence_<frame>.png beside the CSV")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    traced: list[TracedGaussMI] = []
    register("gaussmi_traced", lambda cfg: traced.append(TracedGaussMI(cfg, out.parent if args.images else None))
             or traced[-1])
    cfg = load_config(args.scenario, args.overrides + ["selector.method=gaussmi_traced", f"budget.frames={args.frames}",
                                                       "output.record=false", "evaluation.every=0"])
    with tempfile.TemporaryDirectory() as run:
        Mission(cfg, run, progress=False).run()
    rows = traced[-1].rows
    names = list(dict.fromkeys(k for r in rows for k in r))
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=names, restval="")
        w.writeheader()
        w.writerows(rows)
    print(f"{len(rows)} frames -> {out}")


if __name__ == "__main__":
    main()
