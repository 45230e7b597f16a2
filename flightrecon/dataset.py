"""RGB-D datasets on disk: what a survey flight writes and what the mapper trains on.

Layout of a dataset folder (nerfstudio's `transforms.json` convention, so common tools open it)::

    transforms.json          intrinsics + one entry per frame (below)
    images/frame_00000.png   color, 8-bit RGB
    depth/frame_00000.png    z-depth along the optical axis, 16-bit PNG in millimeters, 0 = invalid
    trajectory.csv           the flown states, one row per control step, columns named in the header
                             (sim.flight.COLUMNS: t, position, quaternion wxyz, velocity, body rates,
                             reference, motor commands and thrusts, clearance)

`transforms.json` keys: `camera_model` ("OPENCV"), `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`,
`k1 k2 p1 p2` (all 0: the simulated camera is an ideal pinhole), `depth_unit_scale_factor`
(0.001: a stored depth value times it gives meters), and `frames`: a list of
`{"file_path": "images/frame_00000.png", "depth_file_path": "depth/frame_00000.png",
"transform_matrix": 4x4 camera-to-world in nerfstudio's OpenGL axes (x right, y up, z back),
"time": seconds of flight at capture}`. When the flight adds pose noise, `transform_matrix` is the
noisy pose (what a mapper would get from a real state estimator) and `true_transform_matrix` the
simulated one. The reader converts back to OpenCV axes (`geometry.opengl_to_opencv_pose`).

Every file is written atomically (`flightrecon.fileio`); a missing or corrupt file read back raises
`DataError` naming it.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from flightrecon import fileio
from flightrecon.errors import DataError
from flightrecon.geometry import opencv_to_opengl_pose, opengl_to_opencv_pose

DEPTH_UNIT = 0.001  # meters per stored depth count (millimeters)
_MAX_DEPTH_COUNT = np.iinfo(np.uint16).max


@dataclass(frozen=True)
class Frame:
    """One RGB-D frame: rgb (H, W, 3) float32 in [0, 1], depth (H, W) float32 meters (0 invalid),
    K (3, 3), T_wc (4, 4) camera-to-world in OpenCV axes as given to mapping, T_wc_true the
    simulated pose (equal to T_wc without pose noise)."""

    rgb: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    T_wc: np.ndarray
    T_wc_true: np.ndarray
    time: float
    name: str


def encode_color_png(rgb: np.ndarray) -> bytes:
    """RGB float in [0, 1] (or uint8) -> PNG bytes."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.round(np.nan_to_num(rgb) * 255.0), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise DataError("could not encode a color image as PNG")
    return buf.tobytes()


def encode_depth_png(depth: np.ndarray) -> bytes:
    """Depth in meters -> 16-bit PNG in millimeters; non-finite, non-positive or out-of-range -> 0."""
    depth = np.asarray(depth, np.float64)
    counts = np.round(np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0) / DEPTH_UNIT)
    counts[(counts <= 0) | (counts > _MAX_DEPTH_COUNT)] = 0
    ok, buf = cv2.imencode(".png", counts.astype(np.uint16))
    if not ok:
        raise DataError("could not encode a depth image as PNG")
    return buf.tobytes()


class DatasetWriter:
    """Writes frames as they are captured; `close()` writes transforms.json (and trajectory.csv).

    Images are written immediately, so a killed flight leaves complete image files; the index is
    written last and atomically, so a dataset with a transforms.json is always whole."""

    def __init__(self, root: str | Path, K: np.ndarray, width: int, height: int) -> None:
        self.root = Path(root)
        self.K = np.asarray(K, float)
        self.width, self.height = int(width), int(height)
        self.frames: list[dict] = []

    def add(self, rgb: np.ndarray, depth: np.ndarray, T_wc: np.ndarray, time: float = 0.0,
            T_wc_true: np.ndarray | None = None) -> str:
        """Store one frame (T_wc in OpenCV axes); returns its name."""
        if rgb.shape[:2] != (self.height, self.width) or depth.shape[:2] != (self.height, self.width):
            raise DataError(f"frame of {rgb.shape[1]}x{rgb.shape[0]} does not match the dataset's "
                            f"{self.width}x{self.height}")
        if not np.all(np.isfinite(T_wc)):
            raise DataError("frame pose holds NaN or inf")
        name = f"frame_{len(self.frames):05d}"
        fileio.write_bytes(self.root / "images" / f"{name}.png", encode_color_png(rgb))
        fileio.write_bytes(self.root / "depth" / f"{name}.png", encode_depth_png(depth))
        entry = {"file_path": f"images/{name}.png", "depth_file_path": f"depth/{name}.png",
                 "transform_matrix": opencv_to_opengl_pose(T_wc).tolist(), "time": float(time)}
        if T_wc_true is not None and not np.allclose(T_wc_true, T_wc):
            entry["true_transform_matrix"] = opencv_to_opengl_pose(T_wc_true).tolist()
        self.frames.append(entry)
        return name

    def close(self, trajectory: dict[str, np.ndarray] | None = None) -> Path:
        """Write trajectory.csv (named equal-length columns) and transforms.json; returns the index path."""
        if trajectory:
            write_trajectory_csv(self.root / "trajectory.csv", trajectory)
        return self.write_index()

    def write_index(self) -> Path:
        """Write transforms.json of the frames so far (atomic: a reader sees the old or the new index)."""
        index = {"camera_model": "OPENCV", "fl_x": float(self.K[0, 0]), "fl_y": float(self.K[1, 1]),
                 "cx": float(self.K[0, 2]), "cy": float(self.K[1, 2]), "w": self.width, "h": self.height,
                 "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "depth_unit_scale_factor": DEPTH_UNIT,
                 "frames": self.frames}
        path = self.root / "transforms.json"
        fileio.write_json(path, index)
        return path


def write_trajectory_csv(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Named 1-D columns of equal length -> CSV with a header row (atomic)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], float).reshape(-1) for n in names])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    w.writerows([[f"{v:.9g}" for v in row] for row in data])
    fileio.write_text(path, buf.getvalue())


def read_trajectory_csv(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a trajectory.csv by name."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        names = rows[0]
        data = np.array([[float(v) for v in r] for r in rows[1:]], float).reshape(-1, len(names))
    except (OSError, IndexError, ValueError) as exc:
        raise DataError(f"trajectory file {path} is missing or corrupt: {exc}") from None
    return {n: data[:, i] for i, n in enumerate(names)}


class Dataset:
    """A dataset folder read back; frames load lazily (`ds[i]`, `for f in ds`), all poses up front."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        index_path = self.root / "transforms.json"
        try:
            index = json.loads(index_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise DataError(f"dataset index {index_path} not found") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"dataset index {index_path} is corrupt: {exc}") from None
        try:
            self.width, self.height = int(index["w"]), int(index["h"])
            self.K = np.array([[float(index["fl_x"]), 0.0, float(index["cx"])],
                               [0.0, float(index["fl_y"]), float(index["cy"])], [0.0, 0.0, 1.0]])
            self.depth_scale = float(index.get("depth_unit_scale_factor", DEPTH_UNIT))
            entries = list(index["frames"])
            self._entries = [self._parse_entry(e) for e in entries]
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"dataset index {index_path} is missing or has a bad field: {exc}") from None
        if not (np.all(np.isfinite(self.K)) and math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise DataError(f"dataset index {index_path} has non-finite intrinsics or depth scale")

    @staticmethod
    def _parse_entry(e: dict) -> dict:
        T = np.array(e["transform_matrix"], float)
        T_true = np.array(e.get("true_transform_matrix", e["transform_matrix"]), float)
        if T.shape != (4, 4) or T_true.shape != (4, 4) or not np.all(np.isfinite(T)) \
                or not np.all(np.isfinite(T_true)):
            raise ValueError(f"transform_matrix of {e.get('file_path')!r} is not a finite 4x4 matrix")
        return {"color": str(e["file_path"]), "depth": str(e["depth_file_path"]),
                "T_wc": opengl_to_opencv_pose(T), "T_wc_true": opengl_to_opencv_pose(T_true),
                "time": float(e.get("time", 0.0))}

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses in OpenCV axes, as given to mapping."""
        return np.array([e["T_wc"] for e in self._entries]).reshape(-1, 4, 4)

    def __getitem__(self, i: int) -> Frame:
        e = self._entries[i]
        rgb = self._read_image(e["color"], cv2.IMREAD_COLOR)
        rgb = cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        raw = self._read_image(e["depth"], cv2.IMREAD_UNCHANGED)
        if raw.ndim != 2 or raw.dtype != np.uint16:
            raise DataError(f"depth image {self.root / e['depth']} is not a single-channel 16-bit PNG")
        depth = raw.astype(np.float32) * np.float32(self.depth_scale)
        for path, img in ((e["color"], rgb), (e["depth"], depth)):
            if img.shape[:2] != (self.height, self.width):
                raise DataError(f"image {self.root / path} is {img.shape[1]}x{img.shape[0]}, "
                                f"the index says {self.width}x{self.height}")
        return Frame(rgb, depth, self.K.copy(), e["T_wc"].copy(), e["T_wc_true"].copy(), e["time"],
                     Path(e["color"]).stem)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def _read_image(self, rel: str, flags: int) -> np.ndarray:
        path = self.root / rel
        try:
            data = np.fromfile(path, np.uint8)
        except OSError:
            raise DataError(f"dataset image {path} not found") from None
        img = cv2.imdecode(data, flags) if data.size else None
        if img is None:
            raise DataError(f"dataset image {path} is corrupt (not a readable PNG)")
        return img

    def trajectory(self) -> dict[str, np.ndarray]:
        """Columns of trajectory.csv (the flown states)."""
        return read_trajectory_csv(self.root / "trajectory.csv")


def load_dataset(root: str | Path) -> Dataset:
    """Open a dataset folder written by `DatasetWriter` (or any nerfstudio RGB-D transforms.json)."""
    return Dataset(root)
