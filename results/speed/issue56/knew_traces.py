"""Does a new frame's loss go flat before K_new ends? The loss of every K_new iteration of the first
N frames of a survey, mapped with the CPU default's mapper but k_new_stop off (so all 60 run), and
how many iterations each stopping rule would have run on those traces.

    python results/speed/issue56/knew_traces.py SURVEY N traces.json   # record (minutes)
    python results/speed/issue56/knew_traces.py --summary traces.json  # the table in README.md
"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np

FLAT_WINDOW = 10


def iterations_run(losses: list[float], share: float, min_iters: int, flat: float = 0.0) -> int:
    """Iterations the mapper runs under k_new_stop = share (after min_iters), optionally also ending once
    the loss fell by less than `flat` of itself over the last FLAT_WINDOW iterations."""
    for i, v in enumerate(losses):
        if i + 1 < min_iters:
            continue
        if v <= share * losses[0] or (flat > 0 and i >= FLAT_WINDOW and v > (1 - flat) * losses[i - FLAT_WINDOW]):
            return i + 1
    return len(losses)


def summary(traces: list[list[float]]) -> None:
    print("| rule | mean K_new iterations | frames that run all 60 |\n|---|---|---|")
    for name, flat in (("k_new_stop 0.3 (the CPU default)", 0.0), ("and flat: < 1% in 10", 0.01),
                       ("and flat: < 2% in 10", 0.02), ("and flat: < 5% in 10", 0.05)):
        runs = [iterations_run(t, 0.3, 20, flat) for t in traces]
        print(f"| {name} | {np.mean(runs):.1f} | {sum(r == len(t) for r, t in zip(runs, traces))} of {len(traces)} |")
    drop = [1 - t[-1] / t[-1 - FLAT_WINDOW] for t in traces]
    print(f"\nloss fall over the last {FLAT_WINDOW} of 60 iterations: median {np.median(drop):.3f}, "
          f"min {min(drop):.3f}")


def record(survey: str, frames: int, out: str) -> None:
    from flightrecon.dataset import load_dataset
    from flightrecon.mapping.mapper import OnlineMapper
    from flightrecon.scenario import load_config

    cfg = load_config("default")
    mapper = OnlineMapper(dataclasses.replace(cfg.mapper, k_new_stop=0.0), near=cfg.camera.near,
                          far=cfg.camera.far, seed=0, device="cpu")
    traces: list[list[float]] = []
    loss, optimize = mapper._loss, mapper._optimize

    def traced_optimize(frame, iters, count_observed=False, **kw):
        if not count_observed:  # a replay iteration
            return optimize(frame, iters, count_observed=count_observed, **kw)
        trace: list[float] = []

        def traced_loss(out, target, *rest):
            value = loss(out, target, *rest)
            trace.append(float(value.detach()))
            return value

        mapper._loss = traced_loss
        try:
            optimize(frame, iters, count_observed=count_observed, **kw)
        finally:
            mapper._loss = loss
        traces.append(trace)

    mapper._optimize = traced_optimize
    data = load_dataset(survey)
    for i in range(frames):
        f = data[i]
        mapper.add_frame(f.rgb, f.depth, f.K, f.T_wc)
    with open(out, "w") as fh:
        json.dump(traces, fh)


if __name__ == "__main__":
    if sys.argv[1] == "--summary":
        with open(sys.argv[2]) as fh:
            summary(json.load(fh))
    else:
        record(sys.argv[1], int(sys.argv[2]), sys.argv[3])
