"""The rerun recording of a flight, read back with rerun's own reader (rerun.chunk: RrdReader, the
store's schema and its chunks, and its dataframe query), plus the `view` command's paths on this headless machine.

The flights are real (MuJoCo, OMPL, ruckig, the C++ rasterizer) at tiny settings. The same seed is
flown with and without recording to show that recording does not change the flight.
"""

import csv
import os
import re
import socket
import subprocess
import sys

import numpy as np
import pytest
import rerun as rr
import trimesh

from flightrecon.errors import FlightReconError
from flightrecon.mission import Mission
from flightrecon.recording import NullRecorder, decimate_mesh, open_recorder, recording_segments
from flightrecon.scenario import load_config
from flightrecon.scene.types import Scene

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=5", "mapper.k_replay=2", "evaluation.views=1", "evaluation.every=0",
        "budget.initial_views=2", "output.record_map_every=2"]
FRAMES = 3
# A 3-frame 80x60 flight: ~1 MB of scene mesh (static) + a few kB per frame; 4 MB leaves room for
# the map snapshots without letting a per-frame blow-up (raw images, the full mesh per frame) pass.
SIZE_BOUND_MB = 4.0
DETERMINISTIC = ("frame", "sim_time", "n_splats", "n_candidates", "n_feasible", "chosen_score", "flight_time",
                 "flight_distance", "recovery", "frame_psnr", "frame_depth_l1_cm", "min_clearance", "contacts")
ENTITIES = ("/world/scene", "/world/drone", "/world/drone/body", "/world/camera", "/world/camera/image",
            "/world/camera/depth", "/rendered/color", "/rendered/depth", "/rendered/normal", "/world/map/splats",
            "/world/map/reliability", "/world/candidates/infeasible", "/world/flown", "/plots/frame_psnr",
            "/plots/frame_depth_l1_cm", "/plots/n_splats", "/plots/clearance", "/events")


def _rows(run_dir):
    with open(run_dir / "frames.csv") as f:
        return list(csv.DictReader(f))


def _store(path):
    return rr.chunk.RrdReader(path).stream().collect()


def _index_values(store, entity: str, column: str) -> list:
    """Every value of a timeline (or the items of a component) over the temporal rows of `entity`."""
    out = []
    for chunk in store.stream().to_chunks():
        if chunk.entity_path == entity and not chunk.is_static:
            for v in chunk.to_record_batch().column(column).to_pylist():
                out.extend(v if isinstance(v, list) else [v])
    return out


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """The same seed flown twice: recorded, and with output.record=false."""
    rec_dir, off_dir = tmp_path_factory.mktemp("recorded"), tmp_path_factory.mktemp("unrecorded")
    Mission(load_config("demo", TINY + [f"budget.frames={FRAMES}"]), rec_dir, progress=False).run()
    recorded_rows = _rows(rec_dir)
    Mission(load_config("demo", TINY + [f"budget.frames={FRAMES}", "output.record=false"]), off_dir,
            progress=False).run()
    return rec_dir, off_dir, recorded_rows


@pytest.mark.slow
def test_recording_reads_back_with_timelines_entities_and_every_frame(flights):
    rec_dir, _, rows = flights
    path = rec_dir / "recording.rrd"
    assert len(rr.chunk.RrdReader(path).blueprints()) == 1  # the default layout travels with the file
    store = _store(path)
    schema = store.schema()
    timelines = {c.name for c in schema.index_columns()}
    assert {"frame", "sim_time"} <= timelines
    paths = set(schema.entity_paths())
    assert set(ENTITIES) <= paths, sorted(set(ENTITIES) - paths)

    frames = [int(r["frame"]) for r in rows]
    assert len(frames) == FRAMES
    for entity in ("/world/camera/image", "/world/camera/depth", "/rendered/color", "/plots/frame_psnr"):
        assert sorted(_index_values(store, entity, "frame")) == frames, entity
    # captures sit at the simulated time the mission wrote for them (duration column, nanoseconds)
    t_ns = _index_values(store, "/world/camera/image", "sim_time")
    t = [v.total_seconds() if hasattr(v, "total_seconds") else v / 1e9 for v in t_ns]
    np.testing.assert_allclose(sorted(t), [float(r["sim_time"]) for r in rows], rtol=1e-5, atol=1e-5)
    # candidates are logged at every step that chose a view (all but the last frame)
    cand = set(_index_values(store, "/world/candidates/infeasible", "frame")) | \
        set(_index_values(store, "/world/candidates/feasible", "frame"))
    assert cand == set(frames[:-1])
    # the map is logged every 2 frames and at the last
    assert sorted(_index_values(store, "/world/map/splats", "frame")) == [0, 2]
    # every line of events.log is in the event log, after the line that opens the segment
    texts = _index_values(store, "/events", "TextLog:text")
    assert sum(t.startswith("recording from frame 0") for t in texts) == 1
    assert set((rec_dir / "events.log").read_text().splitlines()) <= set(texts)
    size_mb = path.stat().st_size / 1e6
    assert size_mb < SIZE_BOUND_MB, size_mb


@pytest.mark.slow
def test_dataframe_query_has_one_capture_row_per_frame(flights):
    """rerun's dataframe query (datafusion) over the frame timeline: the captured images' rows."""
    rec_dir, _, rows = flights
    store = _store(rec_dir / "recording.rrd")
    df = store.reader(index="frame", contents="/world/camera/image").to_pandas()
    image_cols = [c for c in df.columns if c.startswith("/world/camera/image:")]
    assert image_cols, list(df.columns)
    captured = df[df[image_cols].notna().any(axis=1)]
    assert sorted(captured["frame"].tolist()) == [int(r["frame"]) for r in rows]


@pytest.mark.slow
def test_recording_does_not_change_the_flight_and_off_writes_nothing(flights):
    rec_dir, off_dir, recorded_rows = flights
    assert recording_segments(off_dir) == [] and not list(off_dir.glob("*.rrd"))
    off_rows = _rows(off_dir)
    assert [{k: r[k] for k in DETERMINISTIC} for r in off_rows] == \
        [{k: r[k] for k in DETERMINISTIC} for r in recorded_rows]
    assert (rec_dir / "map.ply").read_bytes() == (off_dir / "map.ply").read_bytes()


@pytest.mark.slow
def test_resume_writes_a_second_segment_of_the_same_recording(flights):
    rec_dir = flights[0]
    # extend the finished run by one frame, as a user would after raising the budget
    toml = (rec_dir / "config.toml").read_text()
    (rec_dir / "config.toml").write_text(re.sub(r"(?m)^frames = \d+$", f"frames = {FRAMES + 1}", toml))
    Mission.resume(rec_dir, progress=False).run()
    segs = recording_segments(rec_dir)
    assert [p.name for p in segs] == ["recording.rrd", "recording.resume1.rrd"]
    ids = [rr.chunk.RrdReader(p).recordings()[0].recording_id for p in segs]
    assert ids[0] == ids[1]
    second = _store(segs[1])
    assert sorted(_index_values(second, "/world/camera/image", "frame")) == [FRAMES]
    assert any(t.startswith(f"recording from frame {FRAMES}") for t in _index_values(second, "/events", "TextLog:text"))


def test_no_record_config_gives_the_null_recorder(tmp_path):
    assert isinstance(open_recorder(load_config("demo", ["output.record=false"]), tmp_path), NullRecorder)
    assert list(tmp_path.iterdir()) == []


def test_decimated_scene_mesh_stays_on_the_surface():
    box = trimesh.creation.box(extents=(4.0, 3.0, 2.5))
    for _ in range(5):
        box = box.subdivide()  # 12288 faces, 0.125 m edges
    colors = np.tile(np.array([[200, 100, 50]], np.uint8), (len(box.vertices), 1))
    scene = Scene("box", np.asarray(box.vertices), np.asarray(box.faces), vertex_colors=colors)
    v, f, c = decimate_mesh(scene, 0.2)
    assert 0 < len(f) < len(box.faces) / 3
    assert np.all(f[:, 0] != f[:, 1]) and np.all(f[:, 1] != f[:, 2]) and np.all(f[:, 0] != f[:, 2])
    # merged vertices are means of vertices within one cell: within a cell diagonal of the surface
    _, dist, _ = trimesh.proximity.closest_point(box, v)
    assert dist.max() < 0.2 * np.sqrt(3)
    # the shape survives: the coarse mesh covers the box's area up to the rounded edges
    assert 0.9 < trimesh.Trimesh(v, f, process=False).area / box.area <= 1.0
    assert np.all(c == [200, 100, 50])


def _cli(*args, env=None, timeout=60):
    return subprocess.run([sys.executable, "-m", "flightrecon.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def _tiny_rrd(run_dir):
    rec = rr.RecordingStream("flightrecon-test")
    rec.save(str(run_dir / "recording.rrd"))
    rec.log("world/p", rr.Points3D([[0.0, 0.0, 0.0]]))
    rec.flush()
    rec.disconnect()


def test_view_headless_says_so_and_points_to_web(tmp_path):
    _tiny_rrd(tmp_path)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = _cli("view", str(tmp_path), env=env)
    assert r.returncode == 2
    assert "no display" in r.stderr and "--web" in r.stderr and "Traceback" not in r.stderr


def test_view_without_recording_names_the_folder(tmp_path):
    r = _cli("view", str(tmp_path))
    assert r.returncode == 2 and str(tmp_path) in r.stderr and "recording.rrd" in r.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_view_web_serves_the_recording_and_prints_the_address(tmp_path):
    import urllib.request

    _tiny_rrd(tmp_path)
    web, grpc = _free_port(), _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "flightrecon.cli", "view", str(tmp_path), "--web", "--web-port",
                             str(web), "--grpc-port", str(grpc)], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert f"http://127.0.0.1:{web}/" in line and str(grpc) in line, line
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as resp:
            assert resp.status == 200
        with socket.create_connection(("127.0.0.1", grpc), timeout=10):
            pass
    finally:
        proc.terminate()
        try:  # a hang guard, not a timing: `view` stops its server within its 10 s grace, then kills it
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            left = subprocess.run(["ps", "-eo", "pid,pgid,stat,etime,args"], capture_output=True, text=True).stdout
            proc.kill()
            pytest.fail(f"`view --web` did not exit within 60 s of SIGTERM; processes:\n{left}")
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", web), timeout=2).close()


def _state(pid: int) -> str:
    """The process's state letter from /proc ('gone' once reaped): an oracle apart from `view`'s own check."""
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return "gone"


@pytest.mark.parametrize("child_ignores_sigterm", [False, True])
def test_stopping_the_viewer_ends_its_whole_process_group(child_ignores_sigterm):
    """rerun's server is a wrapper and a binary under it; neither may outlive `view`, even one that
    ignores SIGTERM (it is killed after the grace period)."""
    from flightrecon.commands.view import stop_process_group

    ignore = "signal.signal(signal.SIGTERM, signal.SIG_IGN); " if child_ignores_sigterm else ""
    child = f"import os, signal, time; {ignore}print(os.getpid(), flush=True); time.sleep(600)"
    wrapper = f"import subprocess, sys; subprocess.call([sys.executable, '-c', {child!r}])"
    proc = subprocess.Popen([sys.executable, "-c", wrapper], start_new_session=True, stdout=subprocess.PIPE,
                            text=True)
    child_pid = int(proc.stdout.readline())
    assert _state(child_pid) in "SR"
    stop_process_group(proc, grace_s=1.0)
    assert proc.returncode == -15  # the wrapper ends on SIGTERM either way
    assert _state(child_pid) in ("gone", "Z")  # Z: dead, where PID 1 does not reap orphans


def test_find_recordings_errors_are_user_errors(tmp_path):
    from flightrecon.commands.view import find_recordings

    with pytest.raises(FlightReconError, match="no such run folder"):
        find_recordings(tmp_path / "missing")
