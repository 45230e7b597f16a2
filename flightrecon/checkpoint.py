"""The checkpoint file: versioned state (arrays plus JSON), never pickled objects.

A pickled checkpoint names the classes it holds, so any refactor of them broke resuming an older
run with an unreadable error. A checkpoint here is a plain tree the components' `get_state()` build
(dicts with string keys, lists, numpy arrays, torch tensors, and JSON scalars: bool, int, float,
str, None) and their `set_state()` read back, stored as one uncompressed .npz: each array under its
tree path, plus one JSON document (`HEADER`) holding the format name, `FORMAT_VERSION`, the scalars
and the tree's shape. Tuples come back as lists; torch tensors come back as CPU tensors (callers
move them to their device), numpy arrays as numpy arrays, with their dtype and shape.

Loading never unpickles. A file of another format version, a pickled checkpoint of an earlier
FlightRecon, or a torn file is a CheckpointError naming the file, what it holds and what to do.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from flightrecon import run_folder
from flightrecon.errors import CheckpointError
from flightrecon.fileio import atomic_path

FORMAT = "flightrecon-checkpoint"
FORMAT_VERSION = 1  # raise it whenever a component's state changes meaning; old files are then refused
HEADER = "checkpoint.json"  # the .npz member holding the JSON document
_ARRAYS = "arrays/"  # prefix of the array members, followed by the leaf's tree path
_NDARRAY, _TENSOR = "__ndarray__", "__tensor__"  # the JSON stand-ins of array leaves
_ZIP_MAGIC = b"PK\x03\x04"
_PICKLE_MAGIC = b"\x80"  # pickle protocol 2 and later


def save_checkpoint(path: str | os.PathLike, state: dict) -> None:
    """Write `state` to `path` atomically (a killed run leaves the previous checkpoint whole)."""
    arrays: dict[str, np.ndarray] = {}
    tree = _encode(state, "", arrays)
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "state": tree}
    members = {HEADER: np.frombuffer(json.dumps(header).encode("utf-8"), np.uint8)}
    members.update({_ARRAYS + name: a for name, a in arrays.items()})
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **members)


def load_checkpoint(path: str | os.PathLike) -> dict:
    """The state saved at `path`; a CheckpointError when it is not a readable checkpoint of this
    version (the message says what to do)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(len(_ZIP_MAGIC))
    except OSError as exc:
        raise CheckpointError(f"checkpoint {path} cannot be read ({exc.strerror or exc})") from None
    if magic.startswith(_PICKLE_MAGIC):
        raise CheckpointError(legacy_message(path))
    if magic != _ZIP_MAGIC:
        raise CheckpointError(f"checkpoint {path} is not a FlightRecon checkpoint (it is no .npz file); "
                              f"{_restart(path)}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            header = json.loads(bytes(npz[HEADER]).decode("utf-8"))
            arrays = {name[len(_ARRAYS):]: npz[name] for name in npz.files if name.startswith(_ARRAYS)}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise CheckpointError(f"checkpoint {path} is truncated or corrupt ({exc}); {_restart(path)}") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} is not a FlightRecon checkpoint (no {FORMAT!r} header); "
                              f"{_restart(path)}")
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        age = "a newer" if isinstance(version, int) and version > FORMAT_VERSION else "an older"
        raise CheckpointError(
            f"checkpoint {path} was written by {age} FlightRecon (checkpoint format version {version}; this one "
            f"reads version {FORMAT_VERSION}): finish the run with the FlightRecon that started it, or "
            f"{_restart(path)}")
    try:
        return _decode(header["state"], arrays)
    except (KeyError, TypeError) as exc:
        raise CheckpointError(f"checkpoint {path} is corrupt (it lacks {exc}); {_restart(path)}") from None


def legacy_message(path: str | os.PathLike) -> str:
    """What a user is told about a pickled checkpoint of an earlier FlightRecon at `path`."""
    return (f"checkpoint {path} was written by an older FlightRecon (pickle format), which this version "
            f"does not read: finish the run with the FlightRecon that started it, or {_restart(path)}")


def refuse_legacy(run_dir: str | os.PathLike) -> None:
    """Raise the CheckpointError of `legacy_message` when `run_dir` holds a pickled checkpoint of an
    earlier FlightRecon, so a resume (or a fresh start in that folder) never silently drops it."""
    old = Path(run_dir) / run_folder.LEGACY_CHECKPOINT
    if old.is_file():
        raise CheckpointError(legacy_message(old))


def _restart(path: Path) -> str:
    return f"start the run again: delete {path}"


def _encode(node: Any, where: str, arrays: dict[str, np.ndarray]) -> Any:
    """The JSON tree of `node`; its arrays go to `arrays` under their tree path."""
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if not isinstance(key, str) or key in (_NDARRAY, _TENSOR):
                raise TypeError(f"checkpoint state at {where or '/'}: key {key!r} is not a plain string key")
            out[key] = _encode(value, f"{where}/{key}", arrays)
        return out
    if isinstance(node, (list, tuple)):
        return [_encode(value, f"{where}/{i}", arrays) for i, value in enumerate(node)]
    if isinstance(node, torch.Tensor):
        return {_TENSOR: _add_array(node.detach().cpu().numpy(), where, arrays)}
    if isinstance(node, np.ndarray):
        return {_NDARRAY: _add_array(node, where, arrays)}
    if node is None or isinstance(node, (bool, int, float, str)):
        return node
    raise TypeError(f"checkpoint state at {where or '/'}: a {type(node).__name__} is not an array, tensor or "
                    f"JSON scalar")


def _add_array(a: np.ndarray, where: str, arrays: dict[str, np.ndarray]) -> str:
    if a.dtype.hasobject:
        raise TypeError(f"checkpoint state at {where}: an array of Python objects would need pickle")
    name = where.lstrip("/")
    if name in arrays:
        raise ValueError(f"checkpoint state: two arrays at the path {name!r} (a key holds '/')")
    arrays[name] = a
    return name


def _decode(node: Any, arrays: dict[str, np.ndarray]) -> Any:
    if isinstance(node, dict):
        if _NDARRAY in node:
            return arrays[node[_NDARRAY]]
        if _TENSOR in node:
            return torch.from_numpy(arrays[node[_TENSOR]])
        return {key: _decode(value, arrays) for key, value in node.items()}
    if isinstance(node, list):
        return [_decode(value, arrays) for value in node]
    return node
