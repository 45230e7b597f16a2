"""Where a mapping iteration's time goes: stage timers that `bench map` and `bench run` switch on.

Off by default: `stage(name)` then returns one shared no-op context, so the mapper pays a global
lookup per stage. Inside `profiling()` every stage adds its wall time to the active StageProfile,
and the rasterizer adds its own phases (`add_kernel`: project, bin, blend, reduce, chain, and the
pixel-splat evaluations), which the bench turns into exclusive per-stage times (`breakdown`).
Stages nest (SSIM inside `loss`, the splat axes inside `render` and inside `view setup`): each
stage's time includes the stages inside it, which are also summed per enclosing stage (`inner`), so
`breakdown` reports exclusive times wherever a stage is called from.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator


class StageProfile:
    """Seconds and calls per stage name, and the rasterizer's phase sums per direction."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.inner: dict[str, float] = defaultdict(float)  # per stage, the time of the stages inside it
        self.kernel: dict[str, float] = defaultdict(float)  # "forward.blend_s", "backward.evals", ...
        self.open: list[str] = []  # the stages being timed, outermost first

    def add(self, name: str, seconds: float, parent: str | None = None) -> None:
        self.seconds[name] += seconds
        self.calls[name] += 1
        if parent is not None:
            self.inner[parent] += seconds

    def exclusive(self, name: str) -> float:
        return self.seconds[name] - self.inner[name]

    def add_kernel(self, direction: str, stats: dict[str, float]) -> None:
        for key, value in stats.items():
            self.kernel[f"{direction}.{key}"] += float(value)

    def merge(self, other: "StageProfile") -> None:
        """Add everything `other` timed (a profile collected inside this one's block)."""
        for mine, theirs in ((self.seconds, other.seconds), (self.calls, other.calls), (self.inner, other.inner),
                             (self.kernel, other.kernel)):
            for key, value in theirs.items():
                mine[key] += value


_active: StageProfile | None = None


class _Timer:
    __slots__ = ("profile", "name", "t0")

    def __init__(self, profile: StageProfile, name: str) -> None:
        self.profile, self.name = profile, name

    def __enter__(self) -> None:
        self.profile.open.append(self.name)
        self.t0 = time.perf_counter()

    def __exit__(self, *exc) -> None:
        seconds = time.perf_counter() - self.t0
        self.profile.open.pop()
        self.profile.add(self.name, seconds, self.profile.open[-1] if self.profile.open else None)


class _NoTimer:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc) -> None:
        return None


_NO_TIMER = _NoTimer()


def stage(name: str):
    """A context that times `name` into the active profile; a no-op when none is active."""
    return _NO_TIMER if _active is None else _Timer(_active, name)


def add_kernel(direction: str, stats_fn) -> None:
    """Add the rasterizer's phase stats (`stats_fn()`, read only when profiling) under `direction`."""
    if _active is not None:
        _active.add_kernel(direction, stats_fn())


def active() -> bool:
    return _active is not None


@contextmanager
def profiling() -> Iterator[StageProfile]:
    """Collect stage timings for the duration of the block. Blocks nest: an inner block's timings also
    count in the enclosing one (each flight frame profiles its mapping; `bench run` the whole flight)."""
    global _active
    previous, _active = _active, StageProfile()
    try:
        yield _active
    finally:
        inner, _active = _active, previous
        if previous is not None:
            previous.merge(inner)


# Exclusive stages of the mapping, in pipeline order: per iteration, then per frame.
ITERATION_STAGES = ("splat axes", "project", "bin and sort", "forward blend", "render other", "loss (L1, depth)",
                    "SSIM", "depth normals", "backward blend", "backward reduce and chain", "backward other",
                    "optimizer step", "view setup")
FRAME_STAGES = ("densify", "prune", "other")


def exclusive_seconds(p: StageProfile) -> dict[str, float]:
    """Seconds of each mapping stage (ITERATION_STAGES, then FRAME_STAGES), none counted twice: they
    add up to the time in add_frame."""
    s, k = p.seconds, p.kernel
    fwd_kernel = {name: k[f"forward.{name}_s"] for name in ("project", "bin", "sort", "blend")}
    bwd_kernel = {name: k[f"backward.{name}_s"] for name in ("project", "bin", "sort", "blend", "reduce", "chain")}
    return {
        "splat axes": s["splat axes"] + s["splat axes backward"],  # in render, view setup and backward
        "project": fwd_kernel["project"] + bwd_kernel["project"],
        "bin and sort": fwd_kernel["bin"] + fwd_kernel["sort"] + bwd_kernel["bin"] + bwd_kernel["sort"],
        "forward blend": fwd_kernel["blend"],
        "render other": p.exclusive("render") - sum(fwd_kernel.values()),
        "loss (L1, depth)": p.exclusive("loss"),
        "SSIM": s["ssim"] + s["ssim backward"],
        "depth normals": s["depth normals"] + s["depth normals backward"],
        "backward blend": bwd_kernel["blend"],
        "backward reduce and chain": bwd_kernel["reduce"] + bwd_kernel["chain"],
        "backward other": p.exclusive("backward") - sum(bwd_kernel.values()),
        "optimizer step": p.exclusive("optimizer step"),
        # per optimization call: the target's masks and SSIM moments, the view's culling, the
        # gathered copy of its splats; a replay iteration is a call of its own
        "view setup": p.exclusive("view setup"),
        "densify": p.exclusive("densify"),
        "prune": p.exclusive("prune"),
        "other": p.exclusive("add_frame"),
    }


def breakdown(p: StageProfile, frames: int) -> list[dict]:
    """Rows of exclusive time per stage: ms per iteration (iteration stages) or per frame (the rest),
    and each row's share of all mapping time. `frames`: the add_frame calls profiled."""
    seconds = exclusive_seconds(p)
    iters = max(1, p.calls["render"])
    total = max(p.seconds["add_frame"], 1e-12)
    rows = [{"stage": name, "ms_per_iteration": 1e3 * seconds[name] / iters, "share": seconds[name] / total}
            for name in ITERATION_STAGES]
    rows += [{"stage": name, "ms_per_frame": 1e3 * seconds[name] / max(1, frames), "share": seconds[name] / total}
             for name in FRAME_STAGES]
    return rows


def blend_rates(p: StageProfile, ceiling: dict[str, float], threads: int) -> dict:
    """The forward blend's measured rate against the probe's ceiling (render.extension blend_ceiling):
    evaluations and blends per second per thread, and the share of the blend's time that the same
    evaluations would take at the ceiling (`of_ceiling`) and that its blending evaluations alone would
    take (`useful_of_ceiling`: the rest is waste)."""
    k = p.kernel
    blend_s, evals, blends = k["forward.blend_s"], k["forward.evals"], k["forward.blends"]
    thread_s = max(blend_s * threads, 1e-12)
    t_blend, t_reject = 1.0 / ceiling["blend_per_s_thread"], 1.0 / ceiling["reject_per_s_thread"]
    return {"evals_M_per_s_thread": evals / thread_s / 1e6, "blends_M_per_s_thread": blends / thread_s / 1e6,
            "ceiling_blend_M_per_s_thread": ceiling["blend_per_s_thread"] / 1e6,
            "ceiling_reject_M_per_s_thread": ceiling["reject_per_s_thread"] / 1e6,
            "evals_per_blend": evals / max(blends, 1.0),
            "of_ceiling": ((evals - blends) * t_reject + blends * t_blend) / thread_s,
            "useful_of_ceiling": blends * t_blend / thread_s}
