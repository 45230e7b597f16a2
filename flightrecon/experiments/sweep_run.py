"""One run of a sweep: what it is (`RunSpec`), where it stands (`status`), and bringing it to done
(`run_one`), in the sweep's own process, a pool worker or a Ray node (`experiments.ray_nodes`).

A run is finished when its eval.json exists; a run with a map.ply but no eval.json is only
evaluated; a run with a checkpoint continues with `Mission.resume`. A flight that stops with an
error leaves failed.txt with the reason beside its checkpoint. A run another process flies holds
its `run_lock` claim and is left to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from flightrecon import run_folder, run_lock
from flightrecon.config import ScenarioConfig
from flightrecon.errors import FlightReconError
from flightrecon.fileio import write_text
from flightrecon.memory import keep_freed_memory
from flightrecon.scenario import load_config


@dataclass(frozen=True)
class RunSpec:
    """One (scene, method, seed) of a sweep: plain data, so it travels to pool workers and Ray nodes."""

    scenario: str
    scene: str
    method: str
    seed: int
    overrides: tuple[str, ...]
    run_root: str
    scene_seed: int | None = None  # the scene variant (scene.seed); None: the scenario's own

    @property
    def scene_folder(self) -> str:
        return run_folder.scene_folder(self.scene, self.scene_seed)

    @property
    def run_dir(self) -> Path:
        return Path(self.run_root) / Path(self.scenario).stem / self.scene_folder / self.method / f"seed{self.seed}"

    def config(self) -> ScenarioConfig:
        variant = [] if self.scene_seed is None else [f"scene.seed={self.scene_seed}"]
        return load_config(self.scenario, list(self.overrides) + variant + [
            f"scene.name={self.scene}", f"selector.method={self.method}", f"seed={self.seed}",
            "output.record=false", "evaluation.snapshots=true"])


def status(spec: RunSpec) -> str:
    """done, running (another process holds its claim), failed, evaluate, resume or new."""
    d = spec.run_dir
    if (d / run_folder.EVAL).is_file():
        return "done"
    if run_lock.holder(d) is not None:
        return "running"
    if (d / run_folder.FAILED).is_file():
        return "failed"
    if (d / run_folder.METRICS).is_file() and (d / run_folder.MAP).is_file():
        return "evaluate"
    if (d / run_folder.CHECKPOINT).is_file():
        return "resume"
    return "new"


def failure(spec: RunSpec) -> str | None:
    """Why the run's flight stopped, or None."""
    path = spec.run_dir / run_folder.FAILED
    return path.read_text().strip() if path.is_file() else None


def run_one(spec: RunSpec, threads: int = 0, allow_code_change: bool = False) -> tuple[str, str]:
    """Bring one run to 'done', or to 'failed' when its flight stops with an error (the reason goes
    to failed.txt); returns (run folder, what was done).

    Pool and ray workers start here, not in the CLI, so the malloc tuning the CLI applies to its
    own process is applied here too. Their OpenMP wait policy is already set: they import
    flightrecon (flightrecon.threads) before torch, and inherit the parent's environment."""
    keep_freed_memory()
    if threads > 0:
        import torch

        torch.set_num_threads(threads)
    try:
        with run_lock.claim(spec.run_dir):
            return _fly_and_evaluate(spec, allow_code_change)
    except run_lock.RunInUse as exc:  # another sweep took it since this one planned: its result, not ours
        return str(spec.run_dir), f"skipped ({exc})"


def _fly_and_evaluate(spec: RunSpec, allow_code_change: bool) -> tuple[str, str]:
    from flightrecon.experiments.run_eval import evaluate_run
    from flightrecon.mission import Mission

    state = status(spec)
    if state == "done":
        return str(spec.run_dir), "skipped (finished)"
    if state == "failed":  # asked to retry: fly on from the checkpoint
        (spec.run_dir / run_folder.FAILED).unlink()
        state = status(spec)
    if state in ("new", "resume"):
        try:
            mission = (Mission.resume(spec.run_dir, progress=False) if state == "resume"
                       else Mission(spec.config(), spec.run_dir, progress=False))
            mission.allow_code_change = allow_code_change
            mission.run()
        except FlightReconError as exc:
            write_text(spec.run_dir / run_folder.FAILED, f"{exc}\n")
            return str(spec.run_dir), f"failed: {exc}"
    evaluate_run(spec.run_dir)
    return str(spec.run_dir), {"new": "flown and evaluated", "resume": "resumed and evaluated",
                               "evaluate": "evaluated"}[state]
