"""The process's OpenMP thread policy: waiting threads spin briefly, then sleep.

torch's CPU build and the rasterizer extension share one OpenMP runtime (the libgomp bundled with
torch). By default a waiting libgomp thread (at a barrier, at the end of a parallel region) spins
for GOMP_SPINCOUNT = 300000 rounds before it sleeps. When other processes hold the cores too (a
second flight, sweep workers, a test run), a spinning thread burns the time slice that the thread
it waits for needs, every parallel region ends late, and a frame can take many times its quiet
time. Sleeping at once (OMP_WAIT_POLICY=passive) cures that but costs a futex wake-up at each of
the many small parallel regions of the loss's torch ops, which made a quiet frame a third slower.
A short spin (GOMP_SPINCOUNT=10000) keeps the quiet speed and sleeps long before a time slice is
wasted; `flightrecon bench pair` measures the policies alone and two flights at once.

libgomp reads its variables once, when it is loaded, which is the first `import torch`. So
`import flightrecon` applies the policy before any of its submodules can import torch, and the
environment carries it to subprocesses and to sweep (pool or Ray) workers. A user's own
OMP_WAIT_POLICY or GOMP_SPINCOUNT wins. A program that imports torch before flightrecon keeps
libgomp's default: set GOMP_SPINCOUNT=10000 in the environment, or import flightrecon first.

The number of threads stays libgomp's (one per CPU in the process's affinity mask, which is what
`available_cores` counts); `available_cores` also splits the cores among a sweep's workers.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Mapping, MutableMapping

log = logging.getLogger(__name__)

WAIT_VARIABLES = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")  # either one set by the user: leave both alone
DEFAULT_SPIN = ("GOMP_SPINCOUNT", "10000")

_reported_late = False
# (limit, threads) of the last change a FreeCores made: a sweep worker flies one flight after another
# in one process, and the next flight must start from the limit, not from the count a busy moment of
# the previous one left (a count set since by anyone else is the user's, and kept)
_lowered: tuple[int, int] | None = None


def available_cores() -> int:
    """CPUs this process may run on (its affinity mask, e.g. under taskset or a container's cpuset),
    which can be fewer than the machine's `os.cpu_count()`."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity API (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def apply_wait_policy(environ: MutableMapping[str, str] = os.environ,
                      modules: Mapping[str, object] = sys.modules) -> bool:
    """Default GOMP_SPINCOUNT to a short spin unless the user chose a wait policy or spin count.

    Returns False, and logs once, when torch is already imported: its OpenMP runtime has read the
    variables and keeps what it read, so setting them now would only mislead."""
    global _reported_late
    if "torch" in modules:
        if not _reported_late and not any(v in environ for v in WAIT_VARIABLES):
            log.info("torch was imported before flightrecon: OpenMP threads keep spin-waiting, which slows "
                     "flights sharing the cores with other work; set GOMP_SPINCOUNT=10000 in the environment "
                     "(or import flightrecon first)")
            _reported_late = True
        return False
    if not any(v in environ for v in WAIT_VARIABLES):
        environ[DEFAULT_SPIN[0]] = DEFAULT_SPIN[1]
    return True


class FreeCores:
    """Sizes the process's threads to the cores other processes leave free, once per call of `update`.

    A short spin keeps a flight fast alone, but two flights that each run a thread per core on the
    same cores still wait on each other's time slices at every barrier. Between two calls this
    reads the machine's busy CPU time (/proc/stat) and the process's own (os.times), so the cores
    the others used are busy minus own; the threads are then the remaining cores, at least one and at
    most the count at start (which OMP_NUM_THREADS or torch.set_num_threads may have lowered).
    Where /proc/stat is missing (not Linux) it keeps the threads as they are.
    """

    def __init__(self) -> None:
        import torch

        self._torch = torch
        self.limit = torch.get_num_threads()
        if _lowered is not None and self.limit == _lowered[1]:  # an earlier flight of this process lowered it
            self.limit = _lowered[0]
        self._last = self._sample()

    @staticmethod
    def _sample() -> tuple[float, float, float] | None:
        """(wall s, machine busy CPU s, own CPU s), or None without /proc/stat."""
        try:
            with open("/proc/stat", encoding="ascii") as f:
                fields = [float(v) for v in f.readline().split()[1:]]
        except (OSError, ValueError, IndexError):
            return None
        ticks = os.sysconf("SC_CLK_TCK")
        idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)  # idle + iowait
        own = os.times()
        return time.monotonic(), (sum(fields[:8]) - idle) / ticks, own.user + own.system

    def update(self) -> int:
        """Set and return the threads for the work until the next call."""
        global _lowered
        now = self._sample()
        if now is None or self._last is None or self.limit <= 1:
            return self._torch.get_num_threads()
        wall = now[0] - self._last[0]
        if wall < 0.5:  # too short a window to tell (the tick is 10 ms)
            return self._torch.get_num_threads()
        others = max(0.0, (now[1] - self._last[1]) - (now[2] - self._last[2])) / wall
        self._last = now
        threads = int(min(self.limit, max(1, round(available_cores() - others))))
        if threads != self._torch.get_num_threads():
            self._torch.set_num_threads(threads)
            _lowered = (self.limit, threads)
        return threads
