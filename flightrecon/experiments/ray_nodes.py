"""Sweep runs on the nodes of a Ray cluster that need not share a file system with the driver.

A node that can see the driver's run root (the token the driver wrote there reads back) flies the
run in place. One that cannot flies it under its own node-local root and sends the run's result
files back with the task's answer; the driver writes them into its run folder. The maps, snapshots,
checkpoints and recordings stay on the node: they are large, and the report reads none of them. A
killed run resumes from its checkpoint when Ray sends it to the same node again, else it flies anew.
"""

from __future__ import annotations

import hashlib
import os
import socket
import tempfile
import uuid
from dataclasses import replace
from pathlib import Path

from flightrecon import run_folder
from flightrecon.config import to_toml
from flightrecon.experiments.sweep_run import RunSpec, run_one
from flightrecon.fileio import write_bytes, write_text

# what `experiments.report` reads from a finished run, and what says how it was flown; eval.json
# last, as its presence marks the run finished
RESULT_FILES = (run_folder.CONFIG, run_folder.PROVENANCE, run_folder.FRAMES, run_folder.EVENTS,
                run_folder.DIAGNOSIS, run_folder.TRAJECTORY, run_folder.METRICS, run_folder.FAILED,
                run_folder.OVER_FRAMES, run_folder.NOVEL_VIEW, run_folder.EVAL)
TOKEN_FILE = ".flightrecon-driver"
NODE_ROOT_ENV = "FLIGHTRECON_NODE_RUNS"
TRANSFER_MODES = ("auto", "always", "never")


def node_root() -> Path:
    """Where a node flies runs it cannot write to the driver's run root: $FLIGHTRECON_NODE_RUNS, else
    a folder in the node's temporary directory."""
    return Path(os.environ.get(NODE_ROOT_ENV) or Path(tempfile.gettempdir()) / "flightrecon-node-runs")


def write_token(run_root: str | Path) -> str:
    """A fresh token in the driver's run root, for the nodes to test whether they see it."""
    token = uuid.uuid4().hex
    write_text(Path(run_root) / TOKEN_FILE, token)
    return token


def sees_run_root(run_root: str | Path, token: str) -> bool:
    try:
        return (Path(run_root) / TOKEN_FILE).read_text() == token
    except OSError:
        return False


def run_on_node(spec: RunSpec, threads: int, allow_code_change: bool, token: str, transfer: str,
                scenario_toml: str) -> tuple[str, str, dict[str, bytes] | None]:
    """The Ray task: (driver's run folder, what was done, result files or None when flown in place).
    `scenario_toml` is the run's resolved scenario, so a node needs no copy of the
    driver's scenario file."""
    if transfer == "never" or (transfer == "auto" and sees_run_root(spec.run_root, token)):
        return (*run_one(spec, threads, allow_code_change), None)
    local_root = node_root() / hashlib.sha1(str(Path(spec.run_root).resolve()).encode()).hexdigest()[:12]
    scenario = local_root / "scenarios" / f"{Path(spec.scenario).stem}.toml"
    write_text(scenario, scenario_toml)
    local = replace(spec, scenario=str(scenario), overrides=(), run_root=str(local_root))
    _, what = run_one(local, threads, allow_code_change)
    files = {name: (local.run_dir / name).read_bytes() for name in RESULT_FILES
             if (local.run_dir / name).is_file()}
    return str(spec.run_dir), f"{what} on {socket.gethostname()} in {local.run_dir}, results copied back", files


def receive(run_dir: str | Path, files: dict[str, bytes]) -> None:
    """Write a node's result files into the driver's run folder; a result file the node did not send
    (a failed.txt of an earlier try) is stale and goes."""
    run_dir = Path(run_dir)
    for name in RESULT_FILES:
        if name in files:
            write_bytes(run_dir / name, files[name])
        elif (run_dir / name).is_file():
            (run_dir / name).unlink()


def resolved_scenario(spec: RunSpec) -> str:
    return to_toml(spec.config())
