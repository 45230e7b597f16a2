"""`flightrecon view RUN_DIR --web` seen in a real browser: headless Chromium loads rerun's web viewer
(the wasm app ships inside the rerun-sdk wheel's `rerun` binary and is served by it, nothing is
downloaded), the viewer reads the recording from the command's gRPC server, and a screenshot shows
the 3D view with the flown path.

Chromium is driven over the DevTools protocol on `--remote-debugging-pipe` (JSON messages ending in
a NUL byte on fds 3 and 4), so no client package is needed. WebGL runs on SwiftShader (CPU). The
flight is real (MuJoCo, OMPL, ruckig, the C++ rasterizer) at tiny settings: its ~11k splats keep
SwiftShader quick, where the demo's 60000-splat map snapshots take it over a minute per frame.
"""

import base64
import json
import os
import select
import shutil
import socket
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from flightrecon.mission import Mission
from flightrecon.scenario import load_config

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium)")]

TINY = ["camera.width=80", "camera.height=60", "selector.scoring_width=40", "selector.scoring_height=30",
        "mapper.k_new=5", "mapper.k_replay=2", "evaluation.views=1", "evaluation.every=0",
        "budget.initial_views=2", "budget.frames=4"]
PATH_RGB = (40, 180, 60)  # world/flown and its samples in recording.py
# The samples are shaded spheres: their pixels keep the path's chromaticity (r, g, b) / (r + g + b),
# at 0.4 to 1.6 times its brightness.
PATH_CHROMA_TOL = 0.02
MIN_PATH_PIXELS = 100  # ~600 at 1600x900 for this flight; 0 on the viewer without a recording
LOAD_TIMEOUT_S = 120.0
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         # WebGL on the CPU: ANGLE on SwiftShader (--disable-gpu alone leaves the viewer without WebGL)
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=1600,900"]


class Chromium:
    """Headless Chromium with one page, driven over the DevTools protocol on a pipe."""

    def __init__(self, profile_dir, log_path) -> None:
        to_r, self._to = os.pipe()
        self._from, from_w = os.pipe()

        def fds_3_and_4():  # in the child: the pipe ends Chromium expects, inheritable
            a, b = os.dup(to_r), os.dup(from_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self._log = open(log_path, "w")
        self.proc = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={profile_dir}", "--remote-debugging-pipe",
                                      "about:blank"], preexec_fn=fds_3_and_4, close_fds=False,
                                     stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT)
        os.close(to_r)
        os.close(from_w)
        self._buf, self._id, self.events = b"", 0, []
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Runtime.enable", session=True)
        self.call("Page.enable", session=True)

    def call(self, method: str, session: bool = False, timeout: float = 60.0, **params) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._to, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") != self._id:
                    self.events.append(reply)
                    continue
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            ready, _, _ = select.select([self._from], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise TimeoutError(f"chromium did not answer {method} within {timeout:.0f} s")
            chunk = os.read(self._from, 1 << 20)
            if not chunk:
                raise RuntimeError(f"chromium exited (code {self.proc.poll()}) during {method}")
            self._buf += chunk

    def open(self, url: str) -> None:
        self.call("Page.navigate", session=True, url=url)

    def screenshot(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", session=True, format="png")["data"])

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True)["result"]

    def page_errors(self) -> list[str]:
        out = []
        for e in self.events:
            if e.get("method") == "Runtime.exceptionThrown":
                d = e["params"]["exceptionDetails"]
                out.append(d.get("exception", {}).get("description") or d.get("text", ""))
            elif e.get("method") == "Runtime.consoleAPICalled" and e["params"]["type"] == "error":
                out.append(" ".join(str(a.get("value", "")) for a in e["params"]["args"]))
        return out

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=10)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)
        for fd in (self._to, self._from):
            os.close(fd)
        self._log.close()


def _pixels(png: bytes) -> np.ndarray:
    """RGB, int16."""
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(np.int16)


def path_pixels(png: bytes) -> int:
    """Pixels of the flown path's color in the left half of the page: the blueprint panel and most of
    the 3D view of the default layout (the images on the right, a green normal map among them, are left
    out)."""
    px = _pixels(png)
    px = px[:, : px.shape[1] // 2].astype(np.float64)
    ref = np.asarray(PATH_RGB, np.float64)
    total = px.sum(-1, keepdims=True)
    chroma = px / np.maximum(total, 1.0)
    bright = (total[..., 0] > 0.4 * ref.sum()) & (total[..., 0] < 1.6 * ref.sum())
    return int(((np.abs(chroma - ref / ref.sum()) <= PATH_CHROMA_TOL).all(-1) & bright).sum())


def wait_for_recording(browser: Chromium, timeout: float = LOAD_TIMEOUT_S) -> bytes:
    """Screenshots until the flown path is drawn and the page is at rest (two equal screenshots:
    the images have decoded), or the timeout; the last screenshot."""
    deadline, last = time.monotonic() + timeout, None
    while True:
        time.sleep(2.0)
        shot = browser.screenshot()
        if path_pixels(shot) >= MIN_PATH_PIXELS and shot == last or time.monotonic() > deadline:
            return shot
        last = shot


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("webrun")
    Mission(load_config("demo", TINY), out, progress=False).run()
    assert (out / "recording.rrd").is_file()
    return out


@pytest.fixture
def browser(tmp_path):
    b = Chromium(tmp_path / "profile", tmp_path / "chromium.log")
    yield b
    b.close()


def test_web_view_shows_the_recording_with_the_flown_path(run_dir, browser, tmp_path):
    web, grpc = _free_port(), _free_port()
    view = subprocess.Popen([sys.executable, "-m", "flightrecon.cli", "view", str(run_dir), "--web",
                             "--web-port", str(web), "--grpc-port", str(grpc)], stdout=subprocess.PIPE, text=True)
    try:
        line = view.stdout.readline()
        assert line.startswith("serving 1 recording file(s) at http://127.0.0.1:"), line
        address = line.split(" at ", 1)[1].strip()

        # the viewer alone (no ?url=): the control, with nothing of the flight's color on it
        browser.open(f"http://127.0.0.1:{web}/")
        time.sleep(5.0)
        empty = browser.screenshot()
        (tmp_path / "empty.png").write_bytes(empty)
        webgl = browser.evaluate("!!document.createElement('canvas').getContext('webgl2')")
        assert webgl["value"] is True, "headless chromium has no WebGL2 (SwiftShader flags)"
        assert path_pixels(empty) == 0

        browser.open(address)
        shot = wait_for_recording(browser)
        (tmp_path / "web_view.png").write_bytes(shot)
        px = _pixels(shot)
        n = path_pixels(shot)
        detail = f"screenshot {tmp_path / 'web_view.png'}; page errors: {browser.page_errors()[-5:]}"
        assert px.std() > 20 and len(np.unique(px.reshape(-1, 3), axis=0)) > 1000, "blank page; " + detail
        assert n >= MIN_PATH_PIXELS, f"{n} pixels of the flown path's color; " + detail
        assert shot != empty
    finally:
        view.terminate()  # SIGTERM: `view` stops its rerun server (process group) and exits 0
        assert view.wait(timeout=20) == 0
    for port in (web, grpc):
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
