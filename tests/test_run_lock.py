"""One writer per run folder: a second process (a second sweep over the same run root, a `fly
--resume` beside a sweep) is turned away while the first lives, and a killed one's claim is taken over."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from flightrecon import run_folder, run_lock
from flightrecon.experiments.sweep import execute, plan_runs
from flightrecon.experiments.sweep_run import status

TINY = ["camera.width=80", "camera.height=60", "budget.frames=2", "budget.initial_views=1"]

HOLD = """import sys
from flightrecon import run_lock
with run_lock.claim(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def other_process():
    """Starts a process that claims a folder and keeps it until its stdin closes (or it is killed)."""
    started = []

    def hold(folder: Path) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True)
        started.append(proc)
        assert proc.stdout.readline().strip() == "held"
        return proc

    yield hold
    for proc in started:
        proc.kill()
        proc.wait()


def test_a_live_claim_turns_away_another_process_and_names_the_holder_and_the_file(tmp_path, other_process):
    proc = other_process(tmp_path / "run")
    lock = (tmp_path / "run" / run_folder.LOCK).resolve()
    with pytest.raises(run_lock.RunInUse) as err:
        with run_lock.claim(tmp_path / "run"):
            pass
    assert f"process {proc.pid} on {socket.gethostname()}" in str(err.value) and str(lock) in str(err.value)
    assert run_lock.holder(tmp_path / "run")["pid"] == proc.pid
    proc.stdin.close()  # the holder ends its block: the folder is free and the file gone
    assert proc.wait(timeout=60) == 0
    assert run_lock.holder(tmp_path / "run") is None and not lock.exists()
    with run_lock.claim(tmp_path / "run"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists() and sorted(p.name for p in (tmp_path / "run").iterdir()) == []


def test_the_claim_of_a_killed_process_is_stale_and_taken_over(tmp_path, other_process):
    proc = other_process(tmp_path / "run")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    lock = tmp_path / "run" / run_folder.LOCK
    assert lock.exists()  # SIGKILL runs no cleanup
    assert run_lock.holder(tmp_path / "run") is None
    with run_lock.claim(tmp_path / "run"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    assert not lock.exists()


def test_the_claim_of_a_killed_but_unreaped_process_is_stale(tmp_path, other_process):
    """A zombie still answers kill(pid, 0); where PID 1 does not reap orphans it stays one for good."""
    proc = other_process(tmp_path / "run")
    proc.send_signal(signal.SIGKILL)  # not waited on: a zombie until the fixture reaps it
    deadline = time.monotonic() + 60
    while Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
        assert time.monotonic() < deadline, "the killed holder never became a zombie"
        time.sleep(0.01)
    assert run_lock.holder(tmp_path / "run") is None
    with run_lock.claim(tmp_path / "run"):
        assert json.loads((tmp_path / "run" / run_folder.LOCK).read_text())["pid"] == os.getpid()


@pytest.mark.parametrize("claim, stale", [
    ({"host": socket.gethostname(), "pid": 1, "start": -1}, True),  # pid 1 lives, but started at another time
    ({"host": socket.gethostname(), "pid": 2 ** 22 + 1, "start": None}, True),  # above Linux's pid_max: no process
    ("not json {", True),  # a damaged file
    ({"pid": 5}, True),  # no host
    ({"host": "elsewhere.example", "pid": 1, "start": 0}, False),  # another host: cannot be checked from here
])
def test_which_claims_count_as_stale(tmp_path, claim, stale):
    (tmp_path / run_folder.LOCK).write_text(claim if isinstance(claim, str) else json.dumps(claim))
    assert (run_lock.holder(tmp_path) is None) == stale
    if stale:
        with run_lock.claim(tmp_path):
            pass
    else:
        with pytest.raises(run_lock.RunInUse, match="elsewhere.example.*delete .*flying.lock"):
            with run_lock.claim(tmp_path):
                pass
        assert (tmp_path / run_folder.LOCK).exists()  # left for its owner (or the user) to remove


def test_a_process_may_claim_a_folder_it_holds_and_lets_it_go_once(tmp_path):
    lock = tmp_path / run_folder.LOCK
    with run_lock.claim(tmp_path):
        with run_lock.claim(tmp_path):  # the sweep holds the run, then the flight inside it claims it
            assert run_lock.holder(tmp_path) is None  # this process's own claim is no other's
        assert lock.exists()  # the inner block does not let the outer's claim go
    assert not lock.exists()


def test_a_sweep_skips_a_run_another_process_flies_and_writes_nothing_into_it(tmp_path, other_process):
    spec, = plan_runs("demo", ["room0"], ["random"], 1, TINY, str(tmp_path))
    proc = other_process(spec.run_dir)
    assert status(spec) == "running"
    (run_dir, what), = execute([spec], log=lambda s: None, max_runs=1, retry_failed=True)
    assert run_dir == str(spec.run_dir)
    assert what == f"skipped (being flown by process {proc.pid} on {socket.gethostname()})"
    assert [p.name for p in spec.run_dir.iterdir()] == [run_folder.LOCK]


@pytest.mark.slow
def test_a_mission_refuses_to_fly_a_folder_another_process_flies(tmp_path, other_process):
    from flightrecon.mission import Mission
    from flightrecon.scenario import load_config

    run_dir = tmp_path / "run"
    proc = other_process(run_dir)
    mission = Mission(load_config("demo", TINY), run_dir, progress=False)
    with pytest.raises(run_lock.RunInUse, match=f"process {proc.pid} "):
        mission.run()
    assert [p.name for p in run_dir.iterdir()] == [run_folder.LOCK]
