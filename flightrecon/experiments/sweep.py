"""Run every (scene, method, seed) of a sweep: fly, evaluate, skip what is done, resume what was killed.

Run folders: <output.run_root>/<scenario>/<scene>/<method>/seed<k>/ (the scene level keeps the
eight scenes of one scenario apart); a sweep over scene variants (`scene_seeds`) names the scene
level <scene>.v<scene seed>, so each variant is a scene of its own to the report (its unit). One
run's states and how it is brought to done are `experiments.sweep_run`. A flight that stops with an
error (it diverged, or met bad data) leaves failed.txt with the reason beside its checkpoint: the
sweep goes on with the other runs, reports it, and skips it on later calls unless told to retry
(after the cause is fixed, it resumes from the checkpoint). A run another process flies (a second
sweep over the same root) is skipped, not flown twice (`run_lock`).
Executors: `local` (a process pool of `jobs` workers, inline when jobs = 1) or `ray` (the same task
on a Ray cluster, local or `ray_address`; nodes without the driver's file system send the result
files back: `experiments.ray_nodes`).
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

from flightrecon import run_lock
from flightrecon.active.registry import check_method
from flightrecon.errors import FlightReconError
from flightrecon.experiments import ray_nodes
from flightrecon.experiments.sweep_run import RunSpec, failure, run_one, status
from flightrecon.scenario import load_config
from flightrecon.threads import available_cores


def plan_runs(scenario: str, scenes: list[str], methods: list[str], seeds: int, overrides: list[str],
              run_root: str | None = None, scene_seeds: list[int] | None = None) -> list[RunSpec]:
    """Every combination (of scene variants too, with `scene_seeds`), with config errors raised now
    (before anything runs)."""
    base = load_config(scenario, overrides)
    root = run_root or base.output.run_root
    variants = [None] if scene_seeds is None else list(dict.fromkeys(scene_seeds))
    specs = [RunSpec(scenario, sc, m, k, tuple(overrides), root, v) for sc in scenes for v in variants
             for m in methods for k in range(seeds)]
    for s in specs:
        s.config()
        check_method(s.method, key="sweep --methods")
    return specs


def _skipped(spec: RunSpec, state: str) -> str:
    if state == "done":
        return "skipped (finished)"
    if state == "running":
        claim = run_lock.holder(spec.run_dir)
        return f"skipped (being flown by {run_lock.describe(claim) if claim else 'a process that just ended'})"
    return f"skipped (failed earlier; --retry-failed flies it on): {failure(spec)}"


def execute(specs: list[RunSpec], jobs: int = 1, executor: str = "local", ray_address: str | None = None,
            log=print, max_runs: int | None = None, retry_failed: bool = False,
            allow_code_change: bool = False, transfer: str = "auto") -> list[tuple[str, str]]:
    """Run the specs; finished runs, and failed ones unless `retry_failed`, are skipped without
    starting a worker. With `max_runs`, only the first that many unfinished runs are brought to an
    end (one part of a sweep too long for one sitting; the next call continues with the rest).
    `transfer` (ray only): copy result files back from nodes that cannot see the run root (auto),
    from every node (always), or never."""
    if transfer not in ray_nodes.TRANSFER_MODES:
        raise FlightReconError(f"sweep: transfer must be one of {', '.join(ray_nodes.TRANSFER_MODES)}, "
                               f"got {transfer!r}")
    skip = {"done", "running"} if retry_failed else {"done", "running", "failed"}
    states = [status(s) for s in specs]
    todo = [s for s, state in zip(specs, states) if state not in skip]
    done = [(str(s.run_dir), _skipped(s, state)) for s, state in zip(specs, states) if state in skip]
    for d, what in done:
        log(f"{d}: {what}")
    if max_runs is not None and len(todo) > max_runs:
        log(f"this part runs {max_runs} of the {len(todo)} unfinished runs; the next call continues")
        todo = todo[:max_runs]
    threads = max(1, available_cores() // max(1, jobs))
    if not todo:
        return done
    if executor == "ray":
        return done + _execute_ray(todo, threads, ray_address, log, allow_code_change, transfer)
    if jobs <= 1:
        out = []
        for s in todo:
            out.append(run_one(s, 0, allow_code_change))
            log(f"{out[-1][0]}: {out[-1][1]}")
        return done + out
    out = []
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_end_with_parent,
                             initargs=(os.getpid(),)) as pool:
        for r in pool.map(run_one, todo, [threads] * len(todo), [allow_code_change] * len(todo)):
            out.append(r)
            log(f"{r[0]}: {r[1]}")
    return done + out


def _end_with_parent(parent: int) -> None:
    """Pool worker start: a worker whose sweep is gone (SIGKILL reaches the sweep alone and cannot be
    passed on) ends too, instead of flying the runs already queued to it for nobody. The run it was
    flying resumes from its last checkpoint on the next sweep (its claim is stale once this ends)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="sweep-parent-watch", daemon=True).start()


def _execute_ray(todo: list[RunSpec], threads: int, address: str | None, log,
                 allow_code_change: bool, transfer: str) -> list[tuple[str, str]]:
    try:
        import ray
    except ImportError:
        raise FlightReconError("--executor ray needs the 'ray' package (pip install ray)") from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        tokens = {root: ray_nodes.write_token(root) for root in {s.run_root for s in todo}}
        task = ray.remote(num_cpus=1)(ray_nodes.run_on_node)
        pending = {task.remote(s, threads, allow_code_change, tokens[s.run_root], transfer,
                               ray_nodes.resolved_scenario(s)): s for s in todo}
        out = []
        while pending:  # each run's files land as soon as it ends: a killed driver keeps what came back
            (ready,), _ = ray.wait(list(pending), num_returns=1)
            pending.pop(ready)
            run_dir, what, files = ray.get(ready)
            if files is not None:
                ray_nodes.receive(run_dir, files)
            out.append((run_dir, what))
            log(f"{run_dir}: {what}")
        order = {str(s.run_dir): i for i, s in enumerate(todo)}
        return sorted(out, key=lambda r: order[r[0]])
    finally:
        if started:
            ray.shutdown()
