"""The OpenMP wait policy: a short spin by default, the user's choice wins, set before torch loads
libgomp (which reads it only then), and `bench pair` measures it on a tiny flight."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

import pytest

from flightrecon import threads
from flightrecon.cli import main


def test_a_short_spin_by_default():
    env: dict[str, str] = {}
    assert threads.apply_wait_policy(env, modules={})
    assert env == {"GOMP_SPINCOUNT": "10000"}


@pytest.mark.parametrize("user", [{"OMP_WAIT_POLICY": "passive"}, {"GOMP_SPINCOUNT": "300000"}])
def test_the_users_wait_policy_or_spin_count_wins(user):
    env = dict(user)
    assert threads.apply_wait_policy(env, modules={})
    assert env == user  # either one decides how libgomp waits: nothing is added beside it


def test_too_late_after_torch_is_reported_once(monkeypatch, caplog):
    monkeypatch.setattr(threads, "_reported_late", False)
    env: dict[str, str] = {}
    with caplog.at_level(logging.INFO, logger="flightrecon.threads"):
        assert not threads.apply_wait_policy(env, modules={"torch": object()})
        assert not threads.apply_wait_policy(env, modules={"torch": object()})
    assert env == {}
    assert len([r for r in caplog.records if "GOMP_SPINCOUNT=10000" in r.getMessage()]) == 1


def _fresh_python(code: str, **env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if k not in threads.WAIT_VARIABLES}
    return subprocess.run([sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True,
                          check=True, timeout=120).stdout.strip()


def test_the_cli_sets_the_policy_before_torch_is_imported():
    code = ("import sys, os; import flightrecon.cli; had_torch = 'torch' in sys.modules; import torch; "
            "print(os.environ.get('GOMP_SPINCOUNT'), os.environ.get('OMP_WAIT_POLICY'), had_torch)")
    assert _fresh_python(code) == "10000 None False"
    assert _fresh_python(code, OMP_WAIT_POLICY="active") == "None active False"


def test_available_cores_counts_the_affinity_mask():
    n = threads.available_cores()
    assert 1 <= n <= (os.cpu_count() or 1)
    if hasattr(os, "sched_getaffinity"):
        assert n == len(os.sched_getaffinity(0))


@pytest.mark.slow
def test_bench_pair_flies_alone_then_two_at_once(tmp_path):
    tiny = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
            "mapper.k_new=6", "mapper.k_replay=2", "evaluation.views=2", "evaluation.every=0",
            "budget.initial_views=2"]
    sets = [a for s in tiny for a in ("--set", s)]
    out = tmp_path / "pair.json"
    assert main(["bench", "pair", "--scenario", "demo", "--frames", "2", "--policies", "short", *sets,
                 "--work-dir", str(tmp_path / "runs"), "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["mode"] for r in rows] == ["alone", "pair 0", "pair 1"]
    assert all(r["finished"] and r["frames"] >= 2 and r["map_median_s"] > 0 for r in rows)
    assert all(r["wall_s_ratio"] > 0 for r in rows[1:])
    assert (tmp_path / "runs" / "short" / "pair1" / "frames.csv").is_file()


@pytest.mark.skipif(not os.path.exists("/proc/stat"), reason="reads /proc/stat (Linux)")
def test_free_cores_gives_up_a_thread_to_a_busy_process():
    import time

    import torch

    before = torch.get_num_threads()
    if min(before, threads.available_cores()) < 2:
        pytest.skip("needs two threads on two cores")
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        free = threads.FreeCores()
        time.sleep(1.0)  # a window in which the other process holds a core and this one sleeps
        assert free.update() <= threads.available_cores() - 1
        assert torch.get_num_threads() <= before - 1
        busy.kill()
        busy.wait()
        # the next flight of this process may rise again to the count the first one started from
        assert threads.FreeCores().limit == before
        torch.set_num_threads(before + 1)  # unless someone else has set a count since: that one is kept
        assert threads.FreeCores().limit == before + 1
    finally:
        busy.kill()
        busy.wait()
        torch.set_num_threads(before)
