"""The process's OpenMP thread policy: waiting threads sleep instead of spinning.

torch's CPU build and the rasterizer extension share one OpenMP runtime (the libgomp bundled with
torch). By default its threads spin for a while at every barrier and at the end of every parallel
region before they sleep, which is cheapest on an otherwise idle machine. When other processes hold
the cores too (a second flight, sweep workers, a test run), a spinning thread burns the time slice
that the thread it waits for needs, every parallel region ends late, and a frame can take many
times its quiet time. OMP_WAIT_POLICY=passive makes waiting threads sleep at once; on a quiet
machine that costs a futex wake-up per parallel region (`flightrecon bench pair` measures both).

libgomp reads its variables once, when it is loaded, which is the first `import torch`. So
`import flightrecon` applies the policy before any of its submodules can import torch, and the
environment carries it to subprocesses and to sweep (pool or Ray) workers. A user's own
OMP_WAIT_POLICY or GOMP_SPINCOUNT wins. A program that imports torch before flightrecon keeps
libgomp's default: set OMP_WAIT_POLICY=passive in the environment, or import flightrecon first.

The number of threads stays libgomp's (one per CPU in the process's affinity mask, which is what
`available_cores` counts); `available_cores` also splits the cores among a sweep's workers.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Mapping, MutableMapping

log = logging.getLogger(__name__)

WAIT_VARIABLES = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")  # either one set by the user: leave both alone
DEFAULT_WAIT_POLICY = "passive"

_reported_late = False


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask, e.g. under taskset or a container's cpuset),
    which can be fewer than the machine's `os.cpu_count()`."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def apply_wait_policy(environ: MutableMapping[str, str] = os.environ,
                      modules: Mapping[str, object] = sys.modules) -> bool:
    """Default OMP_WAIT_POLICY to passive unless the user chose a wait policy or spin count.

    Returns False, and logs once, when torch is already imported: its OpenMP runtime has read the
    variables and keeps what it read, so setting them now would only mislead."""
    global _reported_late
    if "torch" in modules:
        if not _reported_late and not any(v in environ for v in WAIT_VARIABLES):
            log.info("torch was imported before flightrecon: OpenMP threads keep spin-waiting, which slows "
                     "flights sharing the cores with other work; set OMP_WAIT_POLICY=passive in the environment "
                     "(or import flightrecon first)")
            _reported_late = True
        return False
    if not any(v in environ for v in WAIT_VARIABLES):
        environ["OMP_WAIT_POLICY"] = DEFAULT_WAIT_POLICY
    return True
