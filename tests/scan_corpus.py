"""A corpus of scan-like meshes (flightrecon.scene.scanify) for tests of the up-direction estimator,
take-off safety and evaluation on holey scans: five scans of each of the eight procedural scenes, in
every file convention, with and without a ceiling, with low walls, holes, furniture on the take-off
spot, in meters, centimeters and millimeters, as PLY with colours and OBJ with a texture atlas.

Imported by name (pytest puts tests/ on the path). Built on first use and cached under the
flightrecon cache folder (`scan_corpus/<key>`), the key hashing the corpus' specification and the
source of the modules that make a scan, so a change to either builds a new corpus:

    from scan_corpus import scan_corpus, select
    for rec in select(scan_corpus(), "camera", exclude=("texture",)):
        scene = load_scene(rec.path, up_axis="auto", unit_scale=rec.meters_per_unit)
        ... compare with rec.up, rec.floor
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import flightrecon.evaluation.tsdf as tsdf
import flightrecon.scene.handheld as handheld
import flightrecon.scene.scanify as scanify
import flightrecon.scene.texture_atlas as texture_atlas
from flightrecon.scene.procedural import GENERATOR_VERSION, SCENE_NAMES
from flightrecon.scene.scanify import ScanOptions, read_truth, scan_procedural, write_scan
from flightrecon.scene.source import cache_root

# small, quick scans: what the tests need is the mess, not the detail
_BASE = dict(frames=60, voxel=0.04, max_faces=60000)
_TEXTURED = dict(_BASE, max_faces=20000)  # an OBJ with its atlas is several times a PLY's size


@dataclass(frozen=True)
class ScanRecord:
    """One scan of the corpus: its mesh file and the truth about it (heights in file units)."""

    path: Path
    scene: str
    seed: int
    kinds: frozenset[str]
    up: np.ndarray  # (3,) unit vector, file coordinates
    floor: float  # floor height along `up`, file units
    meters_per_unit: float
    truth: dict  # the whole sidecar (scanify.read_truth)

    def has(self, *kinds: str) -> bool:
        return set(kinds) <= self.kinds


def corpus_specs() -> list[tuple[str, int, ScanOptions, str]]:
    """(scene, seed, options, file suffix) of every scan: five variants per scene, their details
    turning with the scene's index so that the corpus mixes them."""
    specs = []
    for i, name in enumerate(SCENE_NAMES):
        heading = float((17 + 23 * i) % 90 or 45)
        variants = [
            (dict(_BASE, convention="camera", ceiling="full" if i % 2 == 0 else "partial",
                  units="mm" if i % 4 == 3 else "m"), ".ply"),
            (dict(_TEXTURED, convention="y-up", ceiling="none", holes=5, units="cm" if i % 2 else "m",
                  heading_deg=heading), ".obj"),
            (dict(_BASE, convention="-y-up", wall_top=1.6 + 0.1 * (i % 7), units="mm",
                  offset=(0.5, -1.0, 0.3 * i)), ".ply"),
            (dict(_BASE, convention="z-up", furniture=True, ceiling="partial" if i % 2 == 0 else "full",
                  heading_deg=0.0 if i % 2 == 0 else heading, offset=(0.0, 0.0, -0.8)), ".ply"),
            (dict(_TEXTURED, convention="camera", furniture=True, holes=4, wall_top=2.2 - 0.05 * i), ".obj")
            if i % 2 == 0 else
            (dict(_BASE, convention="camera", ceiling="none", units="mm", holes=8), ".ply"),
        ]
        specs += [(name, j, ScanOptions(**kw), suffix) for j, (kw, suffix) in enumerate(variants)]
    return specs


def corpus_key(specs: list[tuple[str, int, ScanOptions, str]] | None = None) -> str:
    """Hash of the specification and of the source that makes a scan."""
    specs = corpus_specs() if specs is None else specs
    h = hashlib.sha256(json.dumps([[n, s, asdict(o), x] for n, s, o, x in specs], sort_keys=True).encode())
    for module in (scanify, handheld, texture_atlas, tsdf):
        h.update(Path(module.__file__).read_bytes())
    h.update(f"procedural-v{GENERATOR_VERSION}".encode())
    return h.hexdigest()[:16]


def scan_corpus(root: str | os.PathLike | None = None) -> list[ScanRecord]:
    """The corpus' records, building the scans first if the cache does not hold them yet (about
    40 scans; `root`: the cache folder, default flightrecon's cache folder / scan_corpus)."""
    specs = corpus_specs()
    folder = Path(root) if root is not None else cache_root() / "scan_corpus"
    folder /= corpus_key(specs)
    index = folder / "index.json"
    if not index.is_file():
        _build(specs, folder)
    return [_record(folder / name) for name in json.loads(index.read_text())["meshes"]]


def select(records: list[ScanRecord], *kinds: str, exclude: tuple[str, ...] = ()) -> list[ScanRecord]:
    """The records that have every kind in `kinds` and none in `exclude`."""
    return [r for r in records if r.has(*kinds) and not r.kinds & set(exclude)]


def _build(specs, folder: Path) -> None:
    """Write every scan into a temporary folder beside `folder`, then move it in place, so a reader
    never sees half a corpus (and two builders racing both end with a whole one)."""
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        meshes = []
        for name, seed, options, suffix in specs:
            mesh = f"{name}-seed{seed}-{options.convention}{suffix}"
            write_scan(scan_procedural(name, seed, options), tmp / mesh)
            meshes.append(mesh)
        (tmp / "index.json").write_text(json.dumps({"meshes": meshes}, indent=1) + "\n")
        try:
            tmp.rename(folder)
        except OSError:  # another process finished first
            if not (folder / "index.json").is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _record(path: Path) -> ScanRecord:
    truth = read_truth(path)
    return ScanRecord(path=path, scene=truth["scene"], seed=truth["seed"], kinds=frozenset(truth["kinds"]),
                      up=np.asarray(truth["up"], float), floor=float(truth["floor"]),
                      meters_per_unit=float(truth["meters_per_unit"]), truth=truth)
