"""Shared measuring helpers: medians over repeats, machine description, result tables."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from typing import Any, Callable

from flightrecon.errors import FlightReconError
from flightrecon.fileio import write_json


def time_call(fn: Callable[[], Any], repeat: int = 5, warmup: int = 1) -> dict:
    """Run `fn` warmup + repeat times; return median / min / max seconds of the timed runs."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(samples), "min_s": min(samples), "max_s": max(samples),
            "repeat": repeat}


def thread_counts(spec: str, option: str) -> list[int]:
    """Comma-separated thread counts of a bench option (`option` names it in the message); [] for ''."""
    if not spec.strip():
        return []
    try:
        counts = [int(v) for v in spec.split(",")]
    except ValueError:
        raise FlightReconError(f"{option} {spec!r}: give thread counts, e.g. 1,2") from None
    if min(counts) < 1:
        raise FlightReconError(f"{option} {spec!r}: thread counts must be >= 1")
    return counts


def machine() -> dict:
    import torch

    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "cuda": torch.cuda.is_available(),
            "python": platform.python_version(), "torch": torch.__version__,
            "load_avg_1m": round(os.getloadavg()[0], 2)}


def contention_warning(info: dict) -> str | None:
    """A warning when other processes competed for the cores during the run.

    With more runnable threads than cores every parallel region waits for a descheduled thread
    (waiting threads sleep, flightrecon.threads, but the work still shares the cores), so such
    figures are not the project's speed.
    """
    load, cores = info.get("load_avg_1m", 0.0), info.get("cores") or 1
    if load > cores + 0.5:
        return (f"WARNING: load average {load} on {cores} cores at the end of the run: other processes "
                "competed for the CPU, so these timings overstate the quiet figures")
    return None


def report(name: str, rows: list[dict], out: str | None = None, extra: dict | None = None) -> dict:
    """Print rows as a Markdown table and optionally write them, with the machine, as JSON."""
    from flightrecon import provenance

    info = machine()
    # the commit, the CPU model and the package versions it ran with, as every run folder records them
    result = {"bench": name, "machine": info, "provenance": provenance.stamp(), "rows": rows, **(extra or {})}
    if rows:
        print(f"\n## bench {name}\n")
        print(markdown_table(rows))
    for k, v in (extra or {}).items():
        print(f"{k}: {json.dumps(v) if not isinstance(v, str) else v}")
    warning = contention_warning(info)
    if warning:
        print(warning)
    if out:
        write_json(out, result)
    return result


def markdown_table(rows: list[dict]) -> str:
    """Rows as a Markdown table, one column per key in first-seen order (4 significant digits)."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_fmt(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
