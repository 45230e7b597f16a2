"""JIT build and load of the C++ rasterizer (csrc/), cached by source, flags and CPU.

The build directory is $FLIGHTRECON_CACHE/ext/<hash> (default ~/.cache/flightrecon/ext/<hash>), so
an edited source rebuilds and an unchanged one loads in milliseconds. The hash covers the sources,
the compiler flags, torch's version and the CPU's instruction-set features: `-march=native` code
built on one CPU may not run (or may round differently) on another, so a home folder shared
between machines never loads a build made for another CPU.

No `-ffast-math`: it lets GCC flush subnormals to zero and compute sqrt through an approximate
reciprocal square root, which turned zero second moments of the Adam step into NaN on AVX2-only
CPUs while AVX-512 CPUs (another code path) passed. Results must not depend on the CPU.
$FLIGHTRECON_EXT_CFLAGS appends flags, e.g. `-mno-avx512f` to build and test on an AVX-512 host
the code an AVX2-only CPU runs.

torch's cpp_extension needs a C++ compiler and ninja; their absence is reported as one
FlightReconError naming what is missing.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import platform
import shlex
import shutil
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Iterator

from flightrecon.errors import FlightReconError
from flightrecon.resources import resource

log = logging.getLogger(__name__)

CSRC = resource("csrc")
# the rasterizer is one file per pipeline stage around rasterize.h (csrc/rasterize.h lists them)
SOURCES = [CSRC / name for name in (
    "module.cpp", "rasterize.cpp", "rasterize_project.cpp", "rasterize_bin.cpp", "rasterize_forward.cpp",
    "rasterize_backward.cpp", "rasterize_fisher.cpp", "rasterize_feature_sums.cpp", "rasterize_probe.cpp",
    "splat_axes.cpp", "optimizer.cpp", "image_ops.cpp")]
# every header the sources include: the cache key hashes them too
HEADERS = [CSRC / name for name in ("bindings.h", "rasterize.h", "rasterize_blend.h", "rasterize_torch.h")]
CFLAGS = ["-O3", "-march=native", "-fopenmp", "-std=c++17"]
EXTRA_CFLAGS_ENV = "FLIGHTRECON_EXT_CFLAGS"


def cache_dir() -> Path:
    root = os.environ.get("FLIGHTRECON_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "flightrecon")
    return Path(root) / "ext"


def cflags() -> list[str]:
    """The compiler flags of this build: CFLAGS, then those of $FLIGHTRECON_EXT_CFLAGS."""
    return CFLAGS + shlex.split(os.environ.get(EXTRA_CFLAGS_ENV, ""))


def cpu_features() -> str:
    """The CPU's model-independent identity for `-march=native`: its instruction-set flags (Linux),
    else what the platform reports."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return platform.machine() + ":" + " ".join(sorted(line.split(":", 1)[1].split()))
    except OSError:
        pass
    return f"{platform.machine()}:{platform.processor()}"


def source_hash() -> str:
    h = hashlib.sha256()
    # the checkout's path too: torch's build.ninja names the sources by absolute path, so two
    # checkouts sharing one build folder would rebuild it from scratch each time the other ran
    h.update(str(CSRC).encode())
    for src in SOURCES + HEADERS:
        h.update(src.read_bytes())
    h.update(" ".join(cflags()).encode())
    h.update(cpu_features().encode())
    import torch
    h.update(torch.__version__.encode())
    return h.hexdigest()[:16]


def _check_toolchain() -> None:
    missing = [s for s in SOURCES + HEADERS if not s.is_file()]
    if missing:
        raise FlightReconError(f"C++ rasterizer source missing: {missing[0]}")
    cxx = os.environ.get("CXX", "c++")
    if shutil.which(cxx) is None:
        raise FlightReconError(f"cannot build the C++ rasterizer: no C++ compiler ({cxx!r}) on PATH; "
                               "install g++ (e.g. apt-get install g++) or set CXX")
    if shutil.which("ninja") is None:
        # pip's ninja lives in the environment's bin dir, which is not on PATH when the venv's
        # console script is called directly (the Makefile does that)
        try:
            import ninja
            os.environ["PATH"] = ninja.BIN_DIR + os.pathsep + os.environ.get("PATH", "")
        except ImportError:
            pass
    from torch.utils.cpp_extension import is_ninja_available
    if not is_ninja_available():
        raise FlightReconError("cannot build the C++ rasterizer: ninja not found; pip install ninja")


BUILDER_LOCK = "builder.flock"


@contextmanager
def one_builder(build: Path) -> Iterator[None]:
    """Hold the build folder's flock while torch builds or loads in it. The kernel drops the flock when
    its holder dies, so unlike torch's own `lock` file (which a build killed midway leaves behind, and
    every later load then waits on forever, silently) it cannot outlive a killed build. Holding it, any
    torch `lock` found is such a leftover and is removed."""
    with open(build / BUILDER_LOCK, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.info("waiting for another process that is building the C++ rasterizer in %s", build)
            fcntl.flock(handle, fcntl.LOCK_EX)
        leftover = build / "lock"
        if leftover.exists():
            log.warning("removing %s: a build of the C++ rasterizer was killed midway", leftover)
            leftover.unlink(missing_ok=True)
        yield


@lru_cache(maxsize=1)
def load(verbose: bool = False):
    """The compiled module (forward, backward, num_threads); builds it on first use."""
    try:
        from torch.utils import cpp_extension
    except ImportError as exc:  # pragma: no cover - torch is a hard dependency
        raise FlightReconError(f"cannot build the C++ rasterizer: torch is not importable ({exc})")
    _check_toolchain()
    build = cache_dir() / source_hash()
    build.mkdir(parents=True, exist_ok=True)
    try:
        with one_builder(build):
            return cpp_extension.load(name="flightrecon_raster", sources=[str(s) for s in SOURCES],
                                      extra_cflags=cflags(), extra_ldflags=["-fopenmp"],
                                      build_directory=str(build), verbose=verbose)
    except (RuntimeError, OSError) as exc:
        raise FlightReconError(f"building the C++ rasterizer in {build} failed: {exc}") from exc
