"""The package as a user installs it: a wheel built from a clean copy of the tracked files carries the
scenarios, the quadrotor model and the C++ sources inside the package; installed into a fresh
virtual environment outside the checkout, it flies 3 frames of the demo from a temporary folder
and writes nothing into its own install folder."""

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, **kw):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{cmd}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def _files(folder: Path) -> set[str]:
    """Files under the installed package, byte-code caches aside (Python writes those on import)."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


@pytest.mark.slow
def test_wheel_installs_outside_the_checkout_and_flies_the_demo(tmp_path):
    src = tmp_path / "src"
    tracked = _run(["git", "-C", ROOT, "ls-files", "-z"]).stdout.split("\0")
    for name in filter(None, tracked):  # a clean copy: no build/ or egg-info left by an editable install
        if (ROOT / name).is_file() and not name.startswith("results/"):
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes((ROOT / name).read_bytes())
    _run([sys.executable, "-m", "pip", "wheel", src, "--no-deps", "--no-build-isolation", "-q", "-w", tmp_path / "dist"])
    (wheel,) = (tmp_path / "dist").glob("flightrecon-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for shipped in ("flightrecon/_data/scenarios/demo.toml", "flightrecon/_data/scenarios/paper/office0.toml",
                    "flightrecon/_data/models/quadrotor.xml", "flightrecon/_data/csrc/rasterize.h"):
        assert shipped in names, shipped
    assert all(n.startswith(("flightrecon/", "flightrecon-")) for n in names)  # nothing at site-packages' top

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", venv])
    _run([venv / "bin" / "pip", "install", "-q", wheel], timeout=1500)
    site = Path(_run([venv / "bin" / "python", "-c", "import flightrecon, os; print(os.path.dirname("
                                                     "flightrecon.__file__))"], cwd=tmp_path).stdout.strip())
    assert site.is_relative_to(venv) and not site.is_relative_to(ROOT)
    before = _files(site)
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    fly = _run([venv / "bin" / "flightrecon", "fly", "demo", "--set", "budget.frames=3", "--no-record", "--quiet",
                "--out", "run"], cwd=work, env=env, timeout=1500)
    assert "3 frames" in fly.stdout and (work / "run" / "metrics.json").is_file()
    assert _files(site) == before  # the extension built into the user's cache, not into the package
