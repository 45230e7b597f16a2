"""LPIPS, only from weights on local disk: never downloads, else "n/a" with the reason.

The `lpips` package fetches its AlexNet backbone through torchvision on first use, which this
project must not do at run time. So the metric takes one local file: the full state dict of
`lpips.LPIPS(net="alex")` (backbone and linear heads), written once on a machine with network by
`torch.save(lpips.LPIPS(net="alex").state_dict(), "lpips_alex.pth")`, and passed as
`metrics.lpips_weights` (or `flightrecon eval --lpips-weights`). The network is built with random
backbone weights (`pnet_rand=True`, which downloads nothing) and then loads that file.
"""

from __future__ import annotations

from pathlib import Path

import torch


class LpipsMetric:
    """Callable (rgb, rgb_ref) -> LPIPS distance for [H,W,3] images in [0,1], when `available`."""

    def __init__(self, weights: str | Path | None) -> None:
        self.net = None
        self.available = False
        if not weights:
            self.reason = "no local LPIPS weights given (metrics.lpips_weights); nothing is downloaded"
            return
        path = Path(weights).expanduser()
        if not path.is_file():
            self.reason = f"LPIPS weights file {path} not found"
            return
        try:
            import lpips
        except ImportError:
            self.reason = "the 'lpips' package is not installed (pip install lpips)"
            return
        try:
            net = lpips.LPIPS(net="alex", pretrained=False, pnet_rand=True, verbose=False)
            net.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
        except (RuntimeError, OSError, ValueError) as exc:
            self.reason = f"LPIPS weights file {path} does not fit lpips.LPIPS(net='alex'): {exc}"
            return
        self.net = net.eval()
        self.available = True
        self.reason = f"LPIPS (AlexNet) from {path}"

    @torch.no_grad()
    def __call__(self, rgb: torch.Tensor, ref: torch.Tensor) -> float:
        to = lambda x: x.permute(2, 0, 1)[None].float() * 2 - 1  # noqa: E731  (lpips takes [-1, 1])
        return float(self.net(to(rgb), to(ref)))
