"""What a run was flown with: the code (commit, uncommitted changes, the rasterizer build), the CPU
and the versions of the packages that shape its numbers.

A run folder keeps one stamp per flight segment in provenance.json (a resumed flight adds a
segment), so a table can say which code states and CPUs its runs span. Resuming a run with code
other than its last segment's is refused unless asked for (`allow_code_change`), and then recorded.
"""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from flightrecon.errors import FlightReconError
from flightrecon.run_folder import PROVENANCE as FILE

PACKAGES = ("torch", "numpy", "mujoco", "ompl", "ruckig", "open3d", "scipy")  # open3d: or its -cpu wheel
CODE_PATHS = ("flightrecon", "csrc", "scenarios", "models", "pyproject.toml")  # what changes a flight
ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512dq", "amx_tile")
UNSTAMPED = "unstamped"


@dataclass(frozen=True)
class CodeState:
    """The code a flight ran: commit, and a hash of the uncommitted changes to the code (None if clean)."""

    commit: str | None
    diff_hash: str | None

    @property
    def label(self) -> str:
        if self.commit is None:
            return f"package {_version('flightrecon')} (no git checkout)"
        return self.commit[:10] + (f"+dirty:{self.diff_hash[:8]}" if self.diff_hash else "")


def _git(root: Path, *args: str) -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout if r.returncode == 0 else None


def source_root() -> Path:
    """The checkout the package was imported from (its parent folder)."""
    return Path(__file__).resolve().parent.parent


def code_state(root: Path | None = None) -> CodeState:
    """Commit of the checkout holding the package, and a hash of `git diff HEAD` over the code paths
    (untracked files under them included by name and content)."""
    root = root or source_root()
    head = _git(root, "rev-parse", "HEAD")
    if head is None:
        return CodeState(None, None)
    diff = _git(root, "diff", "HEAD", "--", *CODE_PATHS) or ""
    untracked = (_git(root, "ls-files", "--others", "--exclude-standard", "--", *CODE_PATHS) or "").split()
    h = hashlib.sha256(diff.encode())
    for name in sorted(untracked):
        h.update(name.encode())
        try:
            h.update((root / name).read_bytes())
        except OSError:
            pass
    return CodeState(head.strip(), h.hexdigest() if diff or untracked else None)


def _version(name: str) -> str | None:
    for dist in (name, f"{name}-cpu"):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return None


@lru_cache(maxsize=1)
def cpu() -> dict:
    """CPU model, logical cores and the instruction sets that select kernels or change timings."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    except OSError:
        pass
    import os

    return {"model": model, "cores": os.cpu_count(), "isa": [f for f in ISA_FLAGS if f in flags]}


def stamp(started_frame: int = 0) -> dict:
    """Everything a run segment records about how it was run."""
    from flightrecon.render.extension import source_hash

    code = code_state()
    return {
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "started_frame": started_frame,
        "commit": code.commit,
        "dirty": code.diff_hash is not None,
        "diff_hash": code.diff_hash,
        "code_state": code.label,
        "extension_build": source_hash(),
        "cpu": cpu(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "packages": {"flightrecon": _version("flightrecon"), **{p: _version(p) for p in PACKAGES}},
    }


def read(run_dir: str | Path) -> list[dict]:
    """The run's segments, oldest first ([] for a run flown before runs were stamped)."""
    path = Path(run_dir) / FILE
    if not path.is_file():
        return []
    try:
        return json.loads(path.read_text())["segments"]
    except (OSError, ValueError, KeyError) as exc:
        raise FlightReconError(f"{path} cannot be read ({exc}); it records what the run was flown with") from None


def code_states(run_dir: str | Path) -> list[str]:
    """The distinct code states a run's segments ran ([UNSTAMPED] for an unstamped run)."""
    segs = read(run_dir)
    return list(dict.fromkeys(s["code_state"] for s in segs)) if segs else [UNSTAMPED]


def cpus(run_dir: str | Path) -> list[str]:
    return list(dict.fromkeys(s["cpu"]["model"] for s in read(run_dir))) or [UNSTAMPED]


def begin_segment(run_dir: str | Path, started_frame: int, allow_code_change: bool = False) -> dict:
    """Stamp a new flight segment into run_dir/provenance.json. A resumed run (started_frame > 0)
    whose last segment ran other code is refused unless `allow_code_change`; then the segment says so."""
    from flightrecon.fileio import write_json

    run_dir = Path(run_dir)
    segs = read(run_dir)
    now = stamp(started_frame)
    if started_frame > 0:
        last = segs[-1]["code_state"] if segs else UNSTAMPED
        if last != now["code_state"]:
            if not allow_code_change:
                raise FlightReconError(
                    f"cannot resume {run_dir} at frame {started_frame}: its frames so far were flown with code "
                    f"{last}, this is {now['code_state']}; a run that mixes code states cannot be compared with "
                    "others. Check out the run's commit to resume it, fly it anew, or pass --allow-code-change "
                    "to resume anyway (recorded in provenance.json)")
            now["resumed_across_code_change"] = {"from": last}
    elif segs:
        segs = []  # a run started anew in the same folder: its old segments do not describe it
    write_json(run_dir / FILE, {"segments": segs + [now]})
    return now
