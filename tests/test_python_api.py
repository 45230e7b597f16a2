"""The documented Python API: every name `flightrecon` exports resolves, and the runnable example
(examples/scripted_flight.py) steps a flight, scores candidates, renders the saved map and evaluates
the run, from a folder outside the checkout."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import flightrecon

ROOT = Path(__file__).resolve().parents[1]


def test_every_exported_name_resolves_and_an_unknown_one_is_an_attribute_error():
    for name in flightrecon.__all__:
        assert getattr(flightrecon, name) is not None, name
    assert set(flightrecon.__all__) <= set(dir(flightrecon))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        flightrecon.nope  # noqa: B018


@pytest.mark.slow
def test_scripted_flight_example_runs(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "scripted_flight.py"), str(tmp_path / "run")],
                       capture_output=True, text=True, cwd=tmp_path, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    assert lines[0].startswith("frame 0: ") and lines[1].startswith("frame 1: ")
    assert sum(line.startswith("candidate at ") for line in lines) == 3
    assert any(line.startswith("4 frames, flew ") for line in lines)
    assert any(line.startswith("map rendered at the last pose: ") for line in lines)
    assert lines[-1].startswith("evaluate_run: PSNR ")
    for name in ("map.ply", "metrics.json", "eval.json", "checkpoint.npz"):
        assert (tmp_path / "run" / name).is_file(), name
