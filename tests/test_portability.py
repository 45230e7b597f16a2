"""Results that do not depend on the CPU: the extension's cache key, the README demo's first frames,
and, on an AVX-512 host, the kernels built and tested once without AVX-512 (the code an AVX2-only
CPU runs, where the -ffast-math build once turned fresh splats' quaternions into NaN)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from flightrecon.mapping.ply import load_map
from flightrecon.render import extension

ROOT = Path(__file__).resolve().parents[1]
KERNEL_TESTS = ["tests/test_render.py", "tests/test_mapping_store.py", "tests/test_mapping_metrics.py",
                "tests/test_mapping_online.py"]


def test_cache_key_names_the_cpu_and_the_flags(monkeypatch):
    monkeypatch.delenv(extension.EXTRA_CFLAGS_ENV, raising=False)
    base = extension.source_hash()
    assert "-ffast-math" not in extension.cflags()
    monkeypatch.setattr(extension, "cpu_features", lambda: "x86_64:avx avx2 fma sse4_2")
    other_cpu = extension.source_hash()
    monkeypatch.setenv(extension.EXTRA_CFLAGS_ENV, "-mno-avx512f")
    assert extension.cflags()[-1] == "-mno-avx512f"
    other_flags = extension.source_hash()
    assert len({base, other_cpu, other_flags}) == 3


def _fly_demo(out: Path, env: dict, frames: int = 6) -> None:
    """The README demo's settings for `frames` frames through the CLI: it must finish, with every
    map column finite (load_map rejects NaN) and a planned move after the initial turns; the
    3DGS-viewer copy of the map carries scale_2."""
    p = subprocess.run([sys.executable, "-m", "flightrecon.cli", "fly", "demo", "--quiet", "--no-record", "--export-3dgs",
                        "--set", f"budget.frames={frames}", "--out", str(out)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    load_map(out / "map.ply")
    header = (out / "map_3dgs.ply").read_bytes()[:4096].split(b"end_header")[0]
    assert b"property float scale_2" in header
    with open(out / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == frames
    assert float(rows[-2]["flight_distance"]) > 0.1, "the drone never left its take-off point"
    metrics = json.loads((out / "metrics.json").read_text())  # the margin it promises is kept
    assert metrics["contacts"] == 0 and metrics["margin_breach_frames"] == []
    assert metrics["min_clearance_m"] >= metrics["safety_margin_m"] == 0.1


@pytest.mark.slow
def test_demo_first_frames_fly_nan_free(tmp_path):
    _fly_demo(tmp_path / "run", dict(os.environ))


@pytest.mark.slow
@pytest.mark.skipif("avx512f" not in extension.cpu_features().split(),
                    reason="no AVX-512 on this host: the main build already is the AVX2 code")
def test_kernels_and_demo_without_avx512(tmp_path):
    env = dict(os.environ, **{extension.EXTRA_CFLAGS_ENV: "-mno-avx512f"})
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *KERNEL_TESTS],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-2000:]
    _fly_demo(tmp_path / "run", env)


BUILD_AND_HANG = """
import sys, time
from pathlib import Path
from flightrecon.render import extension
build = Path(sys.argv[1])
with extension.one_builder(build):
    (build / "lock").touch()  # what torch's cpp_extension holds while it compiles
    print("building", flush=True)
    time.sleep(600)
"""


def test_a_build_killed_midway_never_blocks_the_next(tmp_path):
    # torch's cpp_extension waits forever on build/lock, and a build killed midway leaves it behind
    builder = subprocess.Popen([sys.executable, "-c", BUILD_AND_HANG, str(tmp_path)], cwd=ROOT,
                               stdout=subprocess.PIPE, text=True)
    try:
        assert builder.stdout.readline().strip() == "building"
        entered = threading.Event()

        def build():
            with extension.one_builder(tmp_path):
                entered.set()

        threading.Thread(target=build, daemon=True).start()
        assert not entered.wait(1.0)  # a live build is waited for
        assert (tmp_path / "lock").exists()
    finally:
        builder.kill()
        builder.wait()
    assert entered.wait(10.0)  # a killed one is not
    assert not (tmp_path / "lock").exists()


def test_the_cache_key_names_the_checkout(monkeypatch):
    base = extension.source_hash()
    monkeypatch.setattr(extension, "CSRC", extension.CSRC.parent / "elsewhere" / "csrc")
    monkeypatch.setattr(extension, "SOURCES", list(extension.SOURCES))  # same files, read from here
    assert extension.source_hash() != base
