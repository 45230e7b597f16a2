"""Evaluation viewpoints written with the scenarios (scenarios/eval_views/<scene>.json).

The loop derives the views deterministically from the scene name and `evaluation.seed`
(flightrecon.evaluation.views), so the file is not needed to reproduce a run; it is there to share
and inspect the exact set (poses T_wc in OpenCV axes, intrinsics, image size), and `load_views`
checks a file against what the loop would use.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from flightrecon.config import SCENARIO_DIR
from flightrecon.errors import DataError
from flightrecon.fileio import write_text

VIEWS_DIR = SCENARIO_DIR / "eval_views"


def views_path(scene_name: str, root: str | Path = VIEWS_DIR) -> Path:
    return Path(root) / f"{scene_name}.json"


def save_views(path: str | Path, scene_name: str, poses: np.ndarray, K: np.ndarray, width: int, height: int,
               seed: int) -> Path:
    doc = {"scene": scene_name, "evaluation_seed": int(seed), "width": int(width), "height": int(height),
           "K": np.asarray(K, float).round(9).tolist(),
           "poses_T_wc": [np.asarray(T, float).round(9).tolist() for T in poses]}
    write_text(Path(path), json.dumps(doc, indent=1) + "\n")
    return Path(path)


def load_views(path: str | Path) -> dict:
    """The stored set: scene, evaluation_seed, width, height, K (3,3), poses (V,4,4)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        poses = np.asarray(doc["poses_T_wc"], float)
        K = np.asarray(doc["K"], float)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or K.shape != (3, 3):
            raise ValueError("poses must be Vx4x4 and K 3x3")
        return {"scene": str(doc["scene"]), "evaluation_seed": int(doc["evaluation_seed"]),
                "width": int(doc["width"]), "height": int(doc["height"]), "K": K, "poses": poses}
    except FileNotFoundError:
        raise DataError(f"evaluation views file {path} not found") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise DataError(f"evaluation views file {path} is malformed: {exc}") from None
