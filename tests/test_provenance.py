"""Run stamps: the code state read from a real git checkout, and resuming across a code change."""

import json
import subprocess

import pytest

from flightrecon import provenance
from flightrecon.errors import FlightReconError


def _git(root, *args):
    subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True)


def test_code_state_names_the_commit_and_hashes_uncommitted_code(tmp_path):
    (tmp_path / "flightrecon").mkdir()
    (tmp_path / "flightrecon" / "a.py").write_text("x = 1\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c")
    head = subprocess.run(["git", "-C", str(tmp_path), "rev-parse", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    clean = provenance.code_state(tmp_path)
    assert clean == provenance.CodeState(head, None) and clean.label == head[:10]
    (tmp_path / "notes.txt").write_text("not code")  # outside the code paths: still clean
    assert provenance.code_state(tmp_path).diff_hash is None
    (tmp_path / "flightrecon" / "a.py").write_text("x = 2\n")
    edited = provenance.code_state(tmp_path)
    assert edited.commit == head and edited.label.startswith(head[:10] + "+dirty:")
    (tmp_path / "flightrecon" / "b.py").write_text("y = 1\n")  # an untracked module changes the state too
    assert provenance.code_state(tmp_path).diff_hash != edited.diff_hash
    assert provenance.code_state(tmp_path / "flightrecon" / "nowhere").commit is None  # no checkout


def test_stamp_records_code_cpu_and_versions():
    s = provenance.stamp()
    assert s["commit"] and len(s["commit"]) == 40  # the tests run in a checkout
    assert s["extension_build"] and s["cpu"]["model"] and s["cpu"]["cores"] >= 1
    assert s["python"].count(".") == 2
    for name in ("torch", "mujoco", "ompl", "ruckig", "open3d", "numpy"):
        assert s["packages"][name], name


def test_resuming_across_a_code_change_is_refused_unless_allowed(tmp_path):
    first = provenance.begin_segment(tmp_path, 0)
    assert provenance.read(tmp_path) == [first]
    provenance.begin_segment(tmp_path, 7)  # same code: a second segment
    assert [s["started_frame"] for s in provenance.read(tmp_path)] == [0, 7]
    segs = provenance.read(tmp_path)
    segs[-1]["code_state"] = "0123456789"  # as if frames 7.. had been flown at another commit
    (tmp_path / "provenance.json").write_text(json.dumps({"segments": segs}))
    with pytest.raises(FlightReconError, match="--allow-code-change"):
        provenance.begin_segment(tmp_path, 12)
    assert len(provenance.read(tmp_path)) == 2  # the refusal wrote nothing
    seg = provenance.begin_segment(tmp_path, 12, allow_code_change=True)
    assert seg["resumed_across_code_change"] == {"from": "0123456789"}
    assert provenance.code_states(tmp_path) == [first["code_state"], "0123456789"]
    provenance.begin_segment(tmp_path, 0)  # flown anew in the same folder: one segment again
    assert len(provenance.read(tmp_path)) == 1


def test_an_unstamped_run_reads_as_such_and_a_corrupt_stamp_names_its_file(tmp_path):
    assert provenance.code_states(tmp_path) == [provenance.UNSTAMPED]
    with pytest.raises(FlightReconError, match="cannot be resumed|at frame 3"):
        provenance.begin_segment(tmp_path, 3)
    (tmp_path / "provenance.json").write_text("{not json")
    with pytest.raises(FlightReconError, match="provenance.json cannot be read"):
        provenance.read(tmp_path)
