"""The malloc tuning takes effect: repeated big allocations stop faulting in fresh pages."""

from __future__ import annotations

import subprocess
import sys

import pytest

from flightrecon.memory import keep_freed_memory

PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "tuned":
    from flightrecon.memory import keep_freed_memory
    assert keep_freed_memory()
def step():  # an iteration's pattern: a few MB-sized temporaries, freed out of order
    a = np.ones(6 << 20, np.float32); b = np.ones(5 << 20, np.float32); c = np.ones(1 << 20, np.float32)
    del b, a
    d = np.ones(3 << 20, np.float32); del c, d
for _ in range(3):  # warm up to the peak
    step()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning is Linux-only")
def test_freed_blocks_are_reused_without_page_faults():
    assert keep_freed_memory()
    default, tuned = _faults("default"), _faults("tuned")
    # glibc trims the freed heap top (or unmaps) each time: ~30k faults; kept, next to none
    assert default > 20 * 500
    assert tuned < default / 20
