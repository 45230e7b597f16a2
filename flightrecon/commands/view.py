"""`flightrecon view RUN_DIR`: open a run's recording in the rerun viewer, or serve it to a browser.

All recording segments of the run (the first flight and every `--resume`) open together, so the
viewer shows one merged timeline. The native viewer needs a display; on a headless machine the
command says so and points to `--web`, which runs rerun's own web viewer and gRPC server and prints
the address to open (forward both ports, e.g. `ssh -L 9090:localhost:9090 -L 9876:localhost:9876`).
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from flightrecon import procfs
from flightrecon.errors import FlightReconError

RERUN = [sys.executable, "-m", "rerun"]  # the viewer that ships with the installed rerun-sdk
START_TIMEOUT_S = 30.0
STOP_GRACE_S = 10.0  # then the viewer's processes are killed


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="open a run's recording.rrd in the rerun viewer (--web: serve it to a browser)")
    p.add_argument("run_dir", help="run folder (or one .rrd file)")
    p.add_argument("--web", action="store_true", help="serve the web viewer and print its address")
    p.add_argument("--host", default="127.0.0.1",
                   help="address the web viewer binds to (0.0.0.0: reachable from other machines)")
    p.add_argument("--web-port", type=int, default=9090, help="HTTP port of the web viewer")
    p.add_argument("--grpc-port", type=int, default=9876, help="port of the gRPC server the web viewer reads from")
    p.set_defaults(func=run)


def find_recordings(target: str | Path) -> list[Path]:
    """The .rrd files to open for a run folder or a single file; a clear error when there are none."""
    target = Path(target)
    if target.is_file() and target.suffix == ".rrd":
        return [target]
    if not target.is_dir():
        raise FlightReconError(f"{target}: no such run folder or .rrd file")
    from flightrecon.recording import recording_segments  # rerun loads only when viewing

    files = recording_segments(target)
    if not files:
        raise FlightReconError(f"{target}: no recording.rrd (was the run flown with --no-record or "
                               "output.record = false?)")
    return files


def run(args: argparse.Namespace) -> int:
    files = [str(f) for f in find_recordings(args.run_dir)]
    if args.web:
        return _serve_web(files, args.host, args.web_port, args.grpc_port)
    from flightrecon.recording import has_display

    if not has_display():
        raise FlightReconError(
            "no display on this machine (DISPLAY and WAYLAND_DISPLAY are unset), so the native rerun viewer "
            f"cannot open. Use `flightrecon view {args.run_dir} --web` and open the printed address in a "
            f"browser (forward the ports over ssh), or copy {files[0]} to a machine with a display and run "
            "`rerun` on it.")
    return subprocess.call([*RERUN, *files])


def _serve_web(files: list[str], host: str, web_port: int, grpc_port: int) -> int:
    """Run rerun's web viewer + gRPC server on the files until Ctrl-C; print the address once it answers."""
    cmd = [*RERUN, "--serve-web", "--bind", host, "--web-viewer-port", str(web_port), "--port", str(grpc_port),
           *files]
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # a terminated `view` stops its server too
    with tempfile.TemporaryFile("w+") as logf:
        # its own process group: `python -m rerun` runs the viewer binary as a child, and both must stop
        proc = subprocess.Popen(cmd, stdout=logf, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            _wait_until_serving(proc, host, web_port, logf)
            shown = socket.gethostname() if host in ("0.0.0.0", "::") else host
            print(f"serving {len(files)} recording file(s) at {_address(web_port, grpc_port, shown)}",
                  flush=True)
            print("press Ctrl-C to stop", flush=True)
            return proc.wait()
        except KeyboardInterrupt:
            return 0
        finally:
            stop_process_group(proc)


def stop_process_group(proc: subprocess.Popen, grace_s: float = STOP_GRACE_S) -> None:
    """End every process in `proc`'s group (its own session): SIGTERM, then SIGKILL what is left after
    `grace_s`. The group, not `proc`, is waited on: `python -m rerun` is a wrapper around the viewer
    binary, the two do not end together, and neither may outlive `view`."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break  # the group is gone
        deadline = time.monotonic() + grace_s  # a killed process, too, dies only once scheduled
        while _group_alive(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        if not _group_alive(proc.pid):
            break
    proc.wait()


def _group_alive(pgid: int) -> bool:
    """Whether a process of the group still runs; zombies do not count (procfs.group_members)."""
    if Path("/proc").is_dir():
        return bool(procfs.group_members(pgid))
    try:  # no procfs: a zombie counts as alive, and the grace period bounds the wait
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def _wait_until_serving(proc: subprocess.Popen, host: str, port: int, logf) -> None:
    probe = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            logf.seek(0)
            tail = logf.read()[-1500:]
            raise FlightReconError(f"the rerun web viewer stopped at start (exit {proc.returncode}; is port "
                                   f"{port} or the gRPC port in use?):\n{tail}")
        try:
            with urllib.request.urlopen(f"http://{probe}:{port}/", timeout=1.0):
                return
        except (urllib.error.URLError, OSError):
            time.sleep(0.2)
    raise FlightReconError(f"the rerun web viewer did not answer on port {port} within {START_TIMEOUT_S:.0f} s")


def _address(web_port: int, grpc_port: int, host: str) -> str:
    from flightrecon.recording import web_viewer_address

    return web_viewer_address(web_port, grpc_port, host)
